"""Change detection against the fleet's common residual (`coplane.roadmap.reference`).

An error that every vehicle of a drive shares (a DGNSS base's multipath, the atmosphere) moves
every tile's passes at once and must not be taken for a change; a road raised on a few tiles must
still be found. Synthetic drives over a straight road of ten tiles, each pass with its own error.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from conftest import Road

from coplane.roadmap import MapBuilder, MapSample, RoadMap, RoadMapConfig, TileKey
from coplane.roadmap.reference import NO_REFERENCE, CommonResidual

ANT = 1.5
SIGMA = 0.3  # the vertical sigma the samples report
ERROR = 0.15  # each pass's own error: half the sigma, as fused solutions' sigmas are (docs/roadmap.md)


def drive(
    road: Road, t0: float, vid: str, rng: np.random.Generator, common_m: float = 0.0, raise_e=None
) -> list:
    """One drive east over e in [-100, 100] m (20 s), 2 m a sample: one error per 20 m stretch
    (about one pass), `common_m` on every sample, and the road raised by `raise_e(e)`."""
    b = MapBuilder(RoadMapConfig())
    errors = rng.normal(0.0, ERROR, 11)
    for j in range(101):
        e = -100.0 + 2.0 * j
        dh = common_m + float(errors[j // 10]) + (raise_e(e) if raise_e else 0.0)
        p = road.antenna_ecef(e, 0.0, ANT, dh)
        b.add(MapSample(vid, t0 + 0.2 * j, p, np.diag([0.04, 0.04, SIGMA**2]), ANT))
    return b.flush()


def drives(road: Road, m: RoadMap, t0: float, n: int, rng: np.random.Generator, **kw) -> set[TileKey]:
    """`n` drives, 5 s apart, by four vehicles in turn; the tiles they flagged as changed."""
    before = {k: t.changes for k, t in m.tiles.items()}
    for k in range(n):
        m.apply(drive(road, t0 + 5.0 * k, f"v{k % 4}", rng, **kw))
    return {k for k, t in m.tiles.items() if t.changes > before.get(k, 0)}


def surveyed(road: Road, config: RoadMapConfig) -> RoadMap:
    m = RoadMap(config)
    assert not drives(road, m, 0.0, 40, np.random.default_rng(3))
    return m


def test_the_reference_needs_enough_recent_passes() -> None:
    cfg = RoadMapConfig(change_reference_window_s=100.0, change_reference_min_passes=5)
    common = CommonResidual(cfg)
    for k in range(4):
        common.add(10.0 * k, 0.1 * k)
    assert common.reference(40.0) is None  # four passes: no change test yet
    common.add(45.0, 5.0)
    common.add(50.0, float("nan"))  # ignored
    ref = common.reference(50.0)
    assert ref is not None and ref.passes == 5 and ref.offset_m == 0.2  # the median, not the mean
    assert common.reference(125.0) is None  # the first passes left the window
    off = CommonResidual(dataclasses.replace(cfg, change_reference=False))
    assert off.reference(0.0) is NO_REFERENCE


def test_a_shift_every_tile_shares_is_not_a_change(road: Road) -> None:
    rng = np.random.default_rng(8)
    for reference, expect_changes in ((True, False), (False, True)):
        m = surveyed(road, RoadMapConfig(change_reference=reference))
        flagged = drives(road, m, 2000.0, 20, rng, common_m=0.9)
        assert bool(flagged) == expect_changes, (reference, len(flagged))


def test_a_road_raised_on_a_few_tiles_is_still_found(road: Road) -> None:
    m = surveyed(road, RoadMapConfig())
    stretch: dict[TileKey, list[float]] = {}  # the e of the drives' road points in each tile
    for e in np.arange(-100.0, 100.1, 2.0):
        tile = m.tile_at(road.road_ecef(float(e), 0.0))
        assert tile is not None
        stretch.setdefault(tile.key, []).append(float(e))
    raised = {k for k, es in stretch.items() if min(es) >= 20.0 and max(es) <= 80.0}
    edge = {k for k, es in stretch.items() if max(es) >= 18.0 and min(es) <= 82.0}  # partly raised
    assert len(raised) >= 2

    def up(e: float) -> float:
        return 1.2 if 20.0 <= e <= 80.0 else 0.0

    # the drives share an error of their own too, which the reference takes off
    flagged = drives(road, m, 2000.0, 20, np.random.default_rng(9), common_m=0.4, raise_e=up)
    assert raised <= flagged, (sorted(raised), sorted(flagged))
    assert flagged <= edge, sorted(flagged - edge)


def test_apply_shows_each_pass_and_what_it_was_tested_against(road: Road) -> None:
    """`RoadMap.apply(on_pass=...)` sees every pass with its update and the common residual it was
    tested against: none while too few passes are at hand, and only usable tiles' passes feed it."""
    cfg = RoadMapConfig(change_reference_min_passes=5)
    m = RoadMap(cfg)
    seen: list[tuple[float, bool, float | None]] = []
    rng = np.random.default_rng(5)
    for k in range(12):
        passes = drive(road, 5.0 * k, f"v{k % 4}", rng)
        m.apply(
            passes,
            on_pass=lambda p, upd, ref, usable: seen.append((upd.residual_m, usable, ref and ref.offset_m)),
        )
    assert len(seen) == sum(t.n_passes + t.outlier_passes for t in m.tiles.values())
    assert seen[0][2] is None and seen[-1][2] is not None  # the reference comes once passes are at hand
    usable_residuals = [r for r, usable, _ in seen if usable]
    assert usable_residuals and all(np.isfinite(usable_residuals))
