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
from coplane.fgo.keys import KeyRegistry, bias_key, clock_key, position_key
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
    links: list[Link] = []
    bias_keys: dict[str, int] = {}
    for bl in p.bias_links:
        bk = bias_keys[bl.system] = bias_key(slot, k, bl.system)
        init_clocks[bk] = bl.init_m
        counts["clock_bias"] = counts.get("clock_bias", 0) + 1
        if bl.prev_key is not None:
            links.append(Link(bl.prev_step, "clock_bias", F.bias_factor(bl.prev_key, bk, bl.sigma_m)))
    prs = p.prs
    if len(prs):
        ref = cks[p.clock_ref] if p.clock_ref is not None else None
        for f in F.pseudorange_factors(
            pk,
            [cks[sys] if ref is None else ref for sys in prs.systems],
            prs.rho,
            prs.sat_pos,
            prs.sat_clock,
            prs.sigma,
            p.init_pos,
            cfg.robust if p.kernel else None,
            cfg.robust_tuning,
            [bias_keys.get(sys) for sys in prs.systems] if bias_keys else None,
        ):
            g.add(f)
        counts["pseudorange"] = len(prs)
    link_kernel = (cfg.robust, cfg.robust_tuning) if cfg.robust_planes_links else (None, None)
    if p.plane is not None:
        g.add(F.plane_factor(pk, p.plane, *link_kernel))
        counts["plane"] = 1
    ln = p.link
    if ln is not None and ln.accel is not None:
        a = ln.accel
        assert a.sigma_up_mps is not None
        cv = F.acceleration_factor(
            (a.prev2_key, ln.prev_key, pk), a.dt0, a.dt1, a.sigma_mps, a.sigma_up_mps, p.init_pos
        )
        links.append(Link(ln.prev_step, ln.kind, cv))
    elif ln is not None:
        disp = F.displacement_factor(
            ln.prev_key, pk, ln.displacement, ln.sigma, p.init_pos, ln.sigma_up, *link_kernel
        )
        links.append(Link(ln.prev_step, ln.kind, disp))
    for s, cl in sorted(p.clock_links.items()):
        factor: gtsam.NonlinearFactor
        if cl.accel is not None:
            keys3 = (cl.accel.prev2_key, cl.prev_key, cks[s])
            factor = F.clock_acceleration_factor(keys3, cl.accel.dt0, cl.accel.dt1, cl.accel.sigma_mps)
        else:
            factor = F.clock_factor(cl.prev_key, cks[s], cl.step_m, cl.sigma_m)
        links.append(Link(cl.prev_step, "clock", factor))
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
        clock_ref=p.clock_ref,
        bias_keys=bias_keys,
        common_cov=p.common_cov,
    )
