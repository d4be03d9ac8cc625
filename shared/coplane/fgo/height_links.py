"""Road-height links: two vehicles a short range apart drive on one road surface.

The paper's plane (eqs. 22-24) needs a history of fleet positions around the vehicle and is
unavailable for about a third of the epochs (docs/results.md), always at a cold start. Its
zeroth-order form needs none: two vehicles whose UWB range is r drive on one surface, so their
antennas' heights differ by the road's grade over r plus the difference of their antenna heights,
within sqrt(sigma^2 + (grade r)^2), and a well-determined height can carry a neighbour's in a
canyon. It belongs to the plane methods (the same road-surface assumption), never to `mci`, and
has the ranges' robust kernel. Off by default (`FgoConfig.height_link_max_m` 0): on the held-out
seeds it cost dense-urban horizontally and the underpasses vertically, where one grade may be the
wrong model (docs/fgo.md, "Road-height links, tried").
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence

from coplane.estimation.validate import ValidRange, ValidVehicle
from coplane.fgo import factors as F
from coplane.fgo.config import FgoConfig
from coplane.fgo.window import RangeEdge, StateBlock


def height_links(
    ranges: Sequence[ValidRange],
    blocks: Mapping[str, StateBlock],
    vehicles: Mapping[str, ValidVehicle],
    cfg: FgoConfig,
    settled: Callable[[str], bool] = lambda vid: True,
) -> list[RangeEdge]:
    """One height link beside every range of this epoch shorter than `cfg.height_link_max_m`.

    A vehicle that does not give its antenna height counts as being at the other's height
    (the sigma floor covers cars against vans)."""
    out: list[RangeEdge] = []
    for r in ranges:
        if r.range_m >= cfg.height_link_max_m or not (settled(r.a) or settled(r.b)):
            continue
        a, b = blocks[r.a], blocks[r.b]
        ha, hb = vehicles[r.a].antenna_height_m, vehicles[r.b].antenna_height_m
        diff = hb - ha if ha is not None and hb is not None else 0.0
        sigma = math.hypot(cfg.height_link_sigma_m, cfg.height_link_grade * r.range_m)
        factor = F.height_link_factor(
            a.pos_key, b.pos_key, a.init_pos, b.init_pos, diff, sigma, cfg.robust, cfg.robust_tuning
        )
        out.append(RangeEdge(r.a, r.b, a.pos_key, b.pos_key, factor, "height_link"))
    return out
