"""A prepared vehicle epoch as GTSAM factors: the `StateBlock` the window keeps.

Each block holds the factors on its own epoch's variables (pseudoranges eq. 21, plane eq. 24) and,
apart, its links to earlier states (velocity eq. 36 or the motion fallback, clock steps), which
die with those states when they leave the window. Built once per vehicle epoch, never rebuilt.
"""

from __future__ import annotations

import gtsam
import numpy as np

from coplane.fgo import factors as F
from coplane.fgo.config import FgoConfig
from coplane.fgo.keys import KeyRegistry, clock_key, position_key
from coplane.fgo.prepare import Prepared
from coplane.fgo.window import Link, StateBlock
from coplane.gtime import GpsTime


def build_block(p: Prepared, k: int, t: GpsTime, keys: KeyRegistry, cfg: FgoConfig) -> StateBlock:
    """The state block of vehicle `p.vid` at epoch index `k` (time `t`)."""
    slot = keys.slot(p.vid)
    pk = position_key(slot, k)
    cks = {s: clock_key(slot, k, s) for s in p.systems}
    g = gtsam.NonlinearFactorGraph()
    counts: dict[str, int] = {}
    init_clocks = {cks[s]: b for s, b in p.clock_init.items()}
    prs = p.prs
    if len(prs):
        for f in F.pseudorange_factors(
            pk,
            [cks[sys] for sys in prs.systems],
            prs.rho,
            prs.sat_pos,
            prs.sat_clock,
            prs.sigma,
            p.init_pos,
            cfg.robust,
            cfg.robust_tuning,
        ):
            g.add(f)
        counts["pseudorange"] = len(prs)
    link_kernel = (cfg.robust, cfg.robust_tuning) if cfg.robust_planes_links else (None, None)
    if p.plane is not None:
        g.add(F.plane_factor(pk, p.plane, *link_kernel))
        counts["plane"] = 1
    links: list[Link] = []
    if p.link is not None:
        disp = F.displacement_factor(
            p.link.prev_key, pk, p.link.displacement, p.link.sigma, p.init_pos, p.link.sigma_up, *link_kernel
        )
        links.append(Link(p.link.prev_step, p.link.kind, disp))
    for s, cl in sorted(p.clock_links.items()):
        links.append(Link(cl.prev_step, "clock", F.clock_factor(cl.prev_key, cks[s], cl.step_m, cl.sigma_m)))
    return StateBlock(
        vehicle_id=p.vid,
        step=k,
        time=t,
        pos_key=pk,
        clock_keys=cks,
        init_pos=np.asarray(p.init_pos, dtype=float),
        init_clocks=init_clocks,
        graph=g,
        counts=counts,
        links=links,
        n_pseudoranges=len(p.prs),
        plane_used=p.plane is not None,
        velocity=p.velocity,
        clock_drift_mps=p.drift,
        has_fix=len(p.prs) >= cfg.min_fix_pseudoranges,
    )
