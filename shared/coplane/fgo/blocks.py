"""A prepared vehicle epoch as GTSAM factors: the `StateBlock` the window keeps.

Each block holds the factors on its own epoch's variables (pseudoranges eq. 21, plane eq. 24) and,
apart, its links to earlier states (velocity eq. 36 or the motion fallback, clock steps), which
die with those states when they leave the window. Made once per vehicle epoch, never remade; the
factors are kept as `Recipe`s, built by the process that solves the block's cluster.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from coplane.fgo import factors as F
from coplane.fgo.config import FgoConfig
from coplane.fgo.keys import KeyRegistry, bias_key, clock_key, position_key
from coplane.fgo.prepare import Prepared
from coplane.fgo.recipes import Recipe
from coplane.fgo.window import Link, StateBlock
from coplane.gtime import GpsTime


def build_block(p: Prepared, k: int, t: GpsTime, keys: KeyRegistry, cfg: FgoConfig) -> StateBlock:
    """The state block of vehicle `p.vid` at epoch index `k` (time `t`)."""
    slot = keys.slot(p.vid)
    pk = position_key(slot, k)
    cks = {s: clock_key(slot, k, s) for s in p.systems}
    own: list[Recipe] = []
    counts: dict[str, int] = {}
    init_clocks = {cks[s]: b for s, b in p.clock_init.items()}
    links: list[Link] = []
    bias_keys: dict[str, int] = {}
    for bl in p.bias_links:
        bk = bias_keys[bl.system] = bias_key(slot, k, bl.system)
        init_clocks[bk] = bl.init_m
        counts["clock_bias"] = counts.get("clock_bias", 0) + 1
        if bl.prev_key is not None:
            links.append(Link(bl.prev_step, "clock_bias", F.bias_factor, bl.prev_key, bk, bl.sigma_m))
    prs = p.prs
    if len(prs):
        ref = cks[p.clock_ref] if p.clock_ref is not None else None
        own.append(
            Recipe(
                F.pseudorange_factors,
                pk,
                tuple([cks[sys] if ref is None else ref for sys in prs.systems]),
                prs.rho,
                prs.sat_pos,
                prs.sat_clock,
                prs.sigma,
                p.init_pos,
                cfg.robust if p.kernel else None,
                cfg.pseudorange_tuning(len(prs)),
                tuple([bias_keys.get(sys) for sys in prs.systems]) if bias_keys else None,
            )
        )
        counts["pseudorange"] = len(prs)
    link_kernel = (cfg.robust, cfg.robust_tuning) if cfg.robust_planes_links else (None, None)
    if p.plane is not None:
        plane = p.plane
        if cfg.plane_sigma_scale != 1.0:
            plane = dataclasses.replace(plane, sigma_m=plane.sigma_m * cfg.plane_sigma_scale)
        own.append(Recipe(F.plane_factor, pk, plane, *link_kernel))
        counts["plane"] = 1
    ln = p.link
    if ln is not None and ln.accel is not None:
        a = ln.accel
        assert a.sigma_up_mps is not None
        keys3 = (a.prev2_key, ln.prev_key, pk)
        accel = (keys3, a.dt0, a.dt1, a.sigma_mps, a.sigma_up_mps, p.init_pos)
        links.append(Link(ln.prev_step, ln.kind, F.acceleration_factor, *accel))
    elif ln is not None:
        disp = (ln.prev_key, pk, ln.displacement, ln.sigma, p.init_pos, ln.sigma_up, *link_kernel)
        links.append(Link(ln.prev_step, ln.kind, F.displacement_factor, *disp))
    for s, cl in sorted(p.clock_links.items()):
        if cl.accel is not None:
            c = cl.accel
            drift = ((c.prev2_key, cl.prev_key, cks[s]), c.dt0, c.dt1, c.sigma_mps)
            links.append(Link(cl.prev_step, "clock", F.clock_acceleration_factor, *drift))
        else:
            step = (cl.prev_key, cks[s], cl.step_m, cl.sigma_m)
            links.append(Link(cl.prev_step, "clock", F.clock_factor, *step))
    return StateBlock(
        vehicle_id=p.vid,
        step=k,
        time=t,
        pos_key=pk,
        clock_keys=cks,
        init_pos=np.asarray(p.init_pos, dtype=float),
        init_clocks=init_clocks,
        recipes=own,
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
        fde_dropped=p.fde_dropped,
        excluded=p.excluded,
    )
