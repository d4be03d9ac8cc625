"""Road-height links: two vehicles a short range apart drive on one road surface.

The paper's plane (eqs. 22-24) needs a history of fleet positions around the vehicle and is
unavailable for about a third of the epochs (docs/results.md), always at a cold start. Its
zeroth-order form needs none: two vehicles whose UWB range is r drive on one surface, so their
antennas' heights differ by the road's grade over r plus the difference of their antenna heights,
within sqrt(sigma^2 + (grade r)^2), and a well-determined height can carry a neighbour's in a
canyon. It belongs to the plane methods (the same road-surface assumption), never to `mci`, and
has the ranges' robust kernel. With `height_link_doppler_grade_sigma` the vehicles' own Doppler
velocities give the road's grade, and the link predicts the height difference along it (a ramp
into an underpass) instead of 0. Off by default (`FgoConfig.height_link_max_m` 0): in three tries
the links won on the training seeds and cost the validation dense-urban seeds horizontally, where
a deep canyon's NLOS-biased pseudoranges trade a better height for a worse horizontal position
(docs/fgo.md, "Road-height links, tried three times").
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence

from coplane.estimation.validate import ValidRange, ValidVehicle
from coplane.fgo import factors as F
from coplane.fgo.config import FgoConfig
from coplane.fgo.window import RangeEdge, StateBlock
from coplane.geo import up_vector
from coplane.typing import Vec

MIN_GRADE_SPEED_MPS = 2.0  # below this the Doppler grade is mostly noise (0.1 m/s vertical = 5 %)
MAX_ROAD_GRADE = 0.15  # a steeper Doppler "grade" is a biased velocity, not a road: no prediction


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
        grade = cfg.height_link_grade
        predicted = _doppler_rise(a.init_pos, b.init_pos, vehicles[r.a], vehicles[r.b], cfg)
        if predicted is not None:
            rise, grade = predicted
            diff += rise
        sigma = math.hypot(cfg.height_link_sigma_m, grade * r.range_m)
        ka, kb = a.pos_key, b.pos_key
        args = (ka, kb, a.init_pos, b.init_pos, diff, sigma, cfg.robust, cfg.robust_tuning)
        out.append(RangeEdge(r.a, r.b, ka, kb, "height_link", F.height_link_factor, *args))
    return out


def _doppler_rise(
    pos_a: Vec, pos_b: Vec, va: ValidVehicle, vb: ValidVehicle, cfg: FgoConfig
) -> tuple[float, float] | None:
    """The road's rise from a to b and its grade's sigma, from both ends' Doppler grades along
    their own headings; None when either end has no grade (or the prediction is off).

    Both ends, because one end's grade says nothing about a change of grade between the two (a
    ramp down into an underpass, the other vehicle already on the flat under the deck): on the
    training seeds predicting from one end cost dense-urban's underpasses a third of their
    vertical accuracy (docs/fgo.md). The two grades' half-difference joins the sigma, since
    it measures a change of grade between them or a biased Doppler. Only the along-heading part
    of the separation rises with the grade; the cross-road part is left to the sigma (a crown or
    a banked curve)."""
    if cfg.height_link_doppler_grade_sigma <= 0:
        return None
    u = up_vector(pos_a)
    d = pos_b - pos_a
    d = d - float(u @ d) * u
    grades: list[float] = []
    rises: list[float] = []
    for v in (va, vb):
        if v.velocity is None:
            return None
        up = float(u @ v.velocity)
        horiz = v.velocity - up * u
        speed = float(math.sqrt(horiz @ horiz))
        if speed < MIN_GRADE_SPEED_MPS or abs(up) > MAX_ROAD_GRADE * speed:
            return None
        grades.append(up / speed)
        rises.append(up / speed * float(d @ horiz) / speed)
    spread = abs(grades[0] - grades[1]) / 2.0
    return sum(rises) / 2.0, math.hypot(cfg.height_link_doppler_grade_sigma, spread)
