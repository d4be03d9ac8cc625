"""One epoch of observations for every receiver: geometry, canyon, tracking, errors -> P, D, C/N0.

Measurement model per receiver r, satellite s, epoch (true GPS time t, receiver tag t + dtr):

  P = rho + c (dtr - dts) + c TGD + I + T + E_common + MP + NLOS + n
  D = -(rho_dot + c (dtr_dot - dts_dot) + NLOS_dot) / lambda + n_D         (RINEX sign)

* rho is the Sagnac-corrected geometric range from the satellite at its true emission time to
  the antenna at t (coplane.sim.sky);
* dts is the broadcast satellite clock with relativity at the emission time; the L1/B1I group
  delay enters as +c TGD because receivers subtract it;
* I, T and E_common are the same for every receiver within a few km; MP, NLOS, n and the
  receiver clock dtr are private to each receiver (coplane.sim.injection, coplane.sim.errors).

A receiver that applies broadcast clocks, TGD, Klobuchar and Saastamoinen therefore sees only
the injected errors. See docs/simulator.md (measurement model).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from coplane.geo import ecef_to_geodetic
from coplane.gnss.constants import WAVELENGTH, C
from coplane.gtime import GpsTime
from coplane.recording.model import ObsEpoch, SatObservation
from coplane.sim.injection import EpochErrors, ErrorInjector
from coplane.sim.sky import enu_rotations, range_rate, satellites_at, sky_view
from coplane.sim.tracking import Tracking
from coplane.sim.visibility import canyon_view
from coplane.sim.world import World
from coplane.typing import AnyArray


@dataclass
class EpochResult:
    """One epoch's observations (one ObsEpoch per receiver row) and what went into them."""

    obs: list[ObsEpoch]
    above: AnyArray  # (N, S) above the elevation mask
    state: AnyArray  # (N, S) BLOCKED / LOS / NLOS
    reported: AnyArray  # (N, S) written to the RINEX file
    el: AnyArray  # (N, S) rad
    cn0: AnyArray  # (N, S) dB-Hz
    errors: EpochErrors


class EpochSimulator:
    """Steps the receivers of a world through its epochs, in order (the error processes have state)."""

    def __init__(self, world: World, seed: int, broadcast_iono: bool = False) -> None:
        self.world = world
        self.errors = ErrorInjector(world, seed, broadcast_iono)
        self.tracking = Tracking(world, seed, self.errors.nlos_cn0_loss_db)
        self.lam = np.array([WAVELENGTH[s[0]] for s in world.sats])

    def step(self, k: int) -> EpochResult:
        """Simulate epoch k (call with k = 0, 1, ... in turn)."""
        w = self.world
        t = w.times[k]
        pos, vel = w.receivers_at(k)
        llh = ecef_to_geodetic(pos)
        rot = enu_rotations(llh[:, 0], llh[:, 1])
        sat = satellites_at(w.nav, w.sats, t, w.origin_ecef, w.rot0)
        view = sky_view(sat, pos, rot)
        above = self.tracking.above_mask(sat.avail, view.el)
        cv = canyon_view(w, k, above, view, sat.vel, pos, vel, rot)
        cn0, reported = self.tracking.step(view.el, above, cv.state)
        err = self.errors.step(k, sat, view.el, above, cv.state, cv.excess_m, cn0, llh)

        clocks = self.errors.clocks
        bias = clocks.bias[k]
        drift = clocks.drift[k]
        isb = self.errors.inter_system_bias_m()
        pr = (
            view.rho + C * bias[:, None] + isb - C * view.sclk + sat.tgd_m[None, :]
            + err.iono_m + err.tropo_m + err.common_m[None, :] + err.multipath_m + err.nlos_m + err.noise_m
        )  # fmt: skip
        rdot = range_rate(view, sat.vel, pos, vel)
        dop = (
            -(rdot + C * (drift[:, None] - sat.drift[None, :]) + cv.excess_rate) / self.lam[None, :]
            + err.doppler_noise_hz
        )
        obs = [
            _obs_epoch(t, float(bias[r]), w.sats, pr[r], dop[r], cn0[r], reported[r]) for r in range(w.n_rx)
        ]
        return EpochResult(obs, above, cv.state, reported, view.el, cn0, err)


def _obs_epoch(
    t: GpsTime, bias_s: float, sats: list[str], pr: AnyArray, dop: AnyArray, cn0: AnyArray, reported: AnyArray
) -> ObsEpoch:
    """One receiver's epoch, tagged with its own clock (t + dtr) like a real receiver's."""
    obs = tuple(
        SatObservation(sats[i], float(pr[i]), float(dop[i]), float(cn0[i])) for i in np.flatnonzero(reported)
    )
    return ObsEpoch(GpsTime(t.week, t.tow + bias_s), obs)
