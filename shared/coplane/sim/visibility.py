"""Which satellites each vehicle sees through the urban canyon at one epoch, and the NLOS extra path.

The canyon model itself (facades, underpasses, reflections) is coplane.sim.canyon; this applies
it to the epoch's geometry. The base station stands in open sky. The extra path of a reflected
signal also changes the Doppler, so its rate is estimated by moving the vehicle and satellite a
moment ahead with the reflecting facade frozen. See docs/simulator.md (urban canyon).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from coplane.sim.canyon import BLOCKED, LOS, NLOS
from coplane.sim.sky import SkyView
from coplane.sim.world import World
from coplane.typing import AnyArray, Mat

RATE_STEP_S = 0.1  # s, look-ahead for the NLOS extra-path rate
MAX_EXCESS_RATE_MPS = 30.0


@dataclass
class CanyonView:
    """Per receiver (N) and satellite (S)."""

    state: AnyArray  # BLOCKED / LOS / NLOS (int8); BLOCKED also for satellites below the mask
    excess_m: AnyArray  # NLOS extra path (m)
    excess_rate: AnyArray  # its time derivative (m/s)


def canyon_view(
    world: World, k: int, above: AnyArray, view: SkyView, sat_vel: Mat, pos: Mat, vel: Mat, rot: AnyArray
) -> CanyonView:
    """Line of sight, reflection or blockage for every satellite above the mask (vehicles only)."""
    track, canyon = world.track, world.canyon
    az, el, spos = view.az, view.el, view.spos
    n_rx, n_sat = above.shape
    state = np.full((n_rx, n_sat), BLOCKED, dtype=np.int8)
    state[above] = LOS
    excess = np.zeros((n_rx, n_sat))
    excess_rate = np.zeros((n_rx, n_sat))
    vi, si = np.nonzero(above[: world.vehicles])
    if len(vi):
        s_v, y_v, h_v = track.s[k][vi], track.y[k][vi], track.antenna_height_m[vi]
        hd = track.heading[k][vi]
        vis = canyon.visibility(s_v, y_v, h_v, hd, az[vi, si][:, None], el[vi, si][:, None])
        st_v = vis.state[:, 0]
        state[vi, si] = st_v
        ex = vis.excess_m[:, 0]
        excess[vi, si] = ex
        nl = st_v == NLOS
        if np.any(nl):
            # extra path a moment later with the reflecting facade frozen -> its time derivative
            delta = RATE_STEP_S
            a, b = vi[nl], si[nl]
            rel = spos[a, b] + sat_vel[b] * delta - (pos[a] + vel[a] * delta)
            e2 = np.einsum("pij,pj->pi", rot[a], rel / np.linalg.norm(rel, axis=1)[:, None])
            az2 = np.arctan2(e2[:, 0], e2[:, 1])
            el2 = np.arcsin(np.clip(e2[:, 2], -1.0, 1.0))
            s2 = track.s[k][a] + track.s_rate[k][a] * delta
            y2 = track.y[k][a] + track.y_rate[k][a] * delta
            _, hd2, _ = world.road.frame(s2)
            ref = vis.reflect_setback_m[nl, 0]
            sg = vis.sign[nl, 0]
            ex1 = canyon.reflection_extra(ref, sg, track.y[k][a], hd[nl], az[a, b], el[a, b])
            ex2 = canyon.reflection_extra(ref, sg, y2, hd2, az2, el2)
            excess_rate[a, b] = np.clip((ex2 - ex1) / delta, -MAX_EXCESS_RATE_MPS, MAX_EXCESS_RATE_MPS)
    return CanyonView(state, excess, excess_rate)
