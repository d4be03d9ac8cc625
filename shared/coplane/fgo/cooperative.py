"""Cooperative fault exclusion: one satellite's residuals across nearby vehicles.

The paper removes NLOS faults before its graph by cooperative integrity monitoring (its ref. [28]).
Vehicles a few tens of metres apart in one street see the same buildings, so an NLOS satellite
is often NLOS at all of them, each time by a bias too small for that vehicle's own w-test
(`screen.py`) to exclude. Added over the m vehicles near one another, the standardised residuals
of a satellite grow like m while their noise grows like sqrt(m): the sum / sqrt(m) tests the
satellite with the fleet's redundancy. The test is one-sided, as NLOS only lengthens a range.

Each vehicle's residuals are those of its own prior-aided FDE (`ScreenResult.w_signed`): at its
own predicted position with its own clocks, so nothing is shared but the satellite's identity.
Written here because it works on the FDE's numpy statistics before any factor exists; GTSAM has
nothing that tests one measurement across several vehicles' graphs.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from coplane.fgo.prepare import Prepared
from coplane.fgo.state import StepStats

MIN_KEEP = 5  # a vehicle keeps this many pseudoranges (one more than a fix needs) whatever the test


def cooperative_exclusion(preps: dict[str, Prepared], k: float, radius_m: float, stats: StepStats) -> None:
    """Exclude, at every vehicle that tracks it, a satellite whose residuals summed over the
    vehicles within `radius_m` (itself included, at least two) exceed k sqrt(m). In place; counted
    `coop_pseudorange`. A vehicle never drops below MIN_KEEP pseudoranges nor loses the last
    satellite of a system (its clock would have nothing left)."""
    tested = {vid: p for vid, p in preps.items() if p.fde_w is not None and len(p.prs)}
    if len(tested) < 2:
        return
    vids = sorted(tested)
    pos = np.array([tested[v].init_pos for v in vids])
    near = np.linalg.norm(pos[:, None, :] - pos[None, :, :], axis=2) <= radius_m
    w_by_sat: list[dict[str, float]] = []
    for v in vids:
        p = tested[v]
        assert p.fde_w is not None
        w_by_sat.append({s: float(w) for s, w in zip(p.prs.sats, p.fde_w, strict=True) if math.isfinite(w)})
    for i, v in enumerate(vids):
        p = tested[v]
        out: set[str] = set()
        for sat in sorted(w_by_sat[i], key=lambda s: -w_by_sat[i][s]):  # the worst first
            ws = [w_by_sat[j][sat] for j in np.flatnonzero(near[i]) if sat in w_by_sat[j]]
            if len(ws) < 2 or sum(ws) <= k * math.sqrt(len(ws)):
                continue
            if len(p.prs) - len(out) <= MIN_KEEP or p.prs.systems.count(sat[0]) - _of(out, sat[0]) <= 1:
                continue
            out.add(sat)
        if out:
            keep = np.array([s not in out for s in p.prs.sats])
            assert p.fde_w is not None  # `tested`
            preps[v] = dataclasses.replace(
                p, prs=p.prs.subset(keep), fde_w=p.fde_w[keep], rank_self=p.rank_self - len(out)
            )
            stats.reject("coop_pseudorange", len(out))


def _of(sats: set[str], system: str) -> int:
    return sum(1 for s in sats if s[0] == system)
