"""PositionHistory: eq. (1) projection, eq. (2) 'before t', eq. (3) radius, down-selection, memory."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from coplane.geo import ecef_to_geodetic, enu_to_ecef, geodetic_to_ecef, up_vector
from coplane.plane import PlaneConfig, PositionHistory, cell_key, project_to_road
from coplane.plane.history import project_many_to_road

LAT, LON = math.radians(35.18), math.radians(136.91)  # Nagoya
REF = geodetic_to_ecef(LAT, LON, 40.0)
CFG = PlaneConfig()


def at(e: float, n: float, u: float = 0.0) -> np.ndarray:
    return enu_to_ecef(np.array([e, n, u]), REF)


def rows(a: np.ndarray) -> list[tuple[float, ...]]:
    return sorted(tuple(r) for r in np.round(a, 6))


# -- eq. (1) --------------------------------------------------------------------------------


@settings(max_examples=40, deadline=None)
@given(lat=st.floats(-1.5, 1.5), lon=st.floats(-3.14, 3.14), hgt=st.floats(-100, 4000), h=st.floats(0, 5))
def test_projection_moves_down_the_ellipsoidal_normal(lat: float, lon: float, hgt: float, h: float) -> None:
    p = geodetic_to_ecef(lat, lon, hgt)
    road = project_to_road(p, h)
    np.testing.assert_allclose(road, p - h * up_vector(p), atol=1e-9)
    lat2, lon2, hgt2 = ecef_to_geodetic(road)  # same normal: same lat/lon, height exactly h lower
    assert hgt2 == pytest.approx(hgt - h, abs=1e-6)
    assert lat2 == pytest.approx(lat, abs=1e-12)
    assert math.cos(lon2 - lon) == pytest.approx(1.0, abs=1e-15)


def test_add_stores_the_road_point_and_batch_add_agrees() -> None:
    rng = np.random.default_rng(0)
    pts = np.array([at(float(rng.uniform(-30, 30)), float(rng.uniform(-30, 30)), 1.5) for _ in range(10)])
    heights = rng.uniform(1.0, 2.5, 10)
    np.testing.assert_allclose(
        project_many_to_road(pts, heights),
        [project_to_road(p, h) for p, h in zip(pts, heights, strict=True)],
        atol=1e-8,
    )
    one, many = PositionHistory(CFG), PositionHistory(CFG)
    for i, (p, h) in enumerate(zip(pts, heights, strict=True)):
        one.add(f"v{i}", 1.0, p, h)
    many.add_many([f"v{i}" for i in range(10)], 1.0, pts, heights)
    a = one.select(REF, 2.0, np.random.default_rng(0))
    b = many.select(REF, 2.0, np.random.default_rng(0))
    np.testing.assert_allclose(a, b, atol=1e-8)
    assert rows(a) == rows(project_many_to_road(pts, heights))


# -- eq. (2): strictly before t, not older than max_history_s ----------------------------------


def test_only_epochs_strictly_before_t() -> None:
    h = PositionHistory(CFG)
    for t in range(10):
        h.add("a", 1000.0 + t, at(t, 0.0), 1.0)
    rng = np.random.default_rng(0)
    times = h.select_records(REF, 1005.0, rng).times_s
    np.testing.assert_array_equal(times, [1000.0, 1001, 1002, 1003, 1004])
    # a time tag a few microseconds off the epoch is the same epoch, still excluded
    np.testing.assert_array_equal(h.select_records(REF, 1005.0 + 5e-6, rng).times_s, times)
    assert h.select(REF, 1000.0, rng).shape == (0, 3)
    short = PositionHistory(replace(CFG, max_history_s=3.0))
    for t in range(10):
        short.add("a", 1000.0 + t, at(t, 0.0), 1.0)
    np.testing.assert_array_equal(short.select_records(REF, 1009.0, rng).times_s, [1006.0, 1007, 1008])


# -- eq. (3): radius --------------------------------------------------------------------------


def test_radius_is_strict_and_three_dimensional() -> None:
    h = PositionHistory(CFG)
    for i, (e, u) in enumerate(
        [(10.0, 0.0), (49.9, 0.0), (50.1, 0.0), (100.0, 0.0), (0.0, 49.0), (0.0, 51.0)]
    ):
        h.add(f"v{i}", 0.0, at(e, 0.0, u + 2.0), 2.0)  # antenna 2 m up: road at height u
    got = h.select_records(REF, 1.0, np.random.default_rng(0))
    assert sorted(got.vehicle_ids) == ["v0", "v1", "v4"]
    assert got.n_candidates == 3


@settings(max_examples=30, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    ce=st.floats(-200, 200),
    cn=st.floats(-200, 200),
    n=st.integers(0, 300),
    cell=st.sampled_from([7.0, 25.0, 50.0, 120.0]),
)
def test_selection_equals_brute_force(seed: int, ce: float, cn: float, n: int, cell: float) -> None:
    """Whatever the cell size, the bucketed query returns exactly the points a full scan finds."""
    cfg = replace(CFG, n_max=1000, cell_size_m=cell)
    rng = np.random.default_rng(seed)
    h = PositionHistory(cfg)
    enu = rng.uniform([-250, -250, -5], [250, 250, 5], (n, 3))
    times = rng.integers(0, 20, n).astype(float)
    vids = [f"v{int(i)}" for i in rng.integers(0, 6, n)]
    for v, t, p in zip(vids, times, enu, strict=True):
        h.add(v, t, enu_to_ecef(p, REF), 1.5)
    centre = at(ce, cn, 1.0)
    got = h.select_records(centre, 12.0, np.random.default_rng(0))
    # brute force over the latest entry of every (vehicle, epoch)
    latest: dict[tuple[str, float], np.ndarray] = {}
    for v, t, p in zip(vids, times, enu, strict=True):
        latest[(v, t)] = project_to_road(enu_to_ecef(p, REF), 1.5)
    want = [
        p for (v, t), p in latest.items() if t < 12.0 and np.linalg.norm(p - centre) < cfg.range_fitting_m
    ]
    assert got.n_candidates == len(want)
    assert rows(got.points) == rows(np.array(want).reshape(-1, 3))
    assert list(got.times_s) == sorted(got.times_s)  # ordered by time


# -- down-selection, determinism -----------------------------------------------------------------


def _forty() -> tuple[PositionHistory, np.ndarray]:
    h = PositionHistory(CFG)
    pts = []
    for i in range(40):
        p = at(math.cos(i) * 30, math.sin(i) * 30, 1.0)
        h.add(f"v{i % 4}", float(i // 4), p, 1.0)
        pts.append(project_to_road(p, 1.0))
    return h, np.array(pts)


def test_down_selection_is_random_but_seeded() -> None:
    h, pts = _forty()
    a = h.select_records(REF, 100.0, np.random.default_rng(42))
    b = h.select_records(REF, 100.0, np.random.default_rng(42))
    assert a.n_candidates == 40 and a.points.shape == (CFG.n_max, 3)
    np.testing.assert_array_equal(a.points, b.points)
    assert set(rows(a.points)) <= set(rows(pts))
    assert len(set(rows(a.points))) == CFG.n_max  # without replacement
    seen = set()
    for seed in range(20):
        seen |= set(rows(h.select(REF, 100.0, np.random.default_rng(seed))))
    assert len(seen) > 30  # different seeds draw different subsets


def test_selection_does_not_depend_on_insertion_order() -> None:
    h1, _ = _forty()
    h2 = PositionHistory(CFG)
    records = [(f"v{i % 4}", float(i // 4), at(math.cos(i) * 30, math.sin(i) * 30, 1.0)) for i in range(40)]
    for v, t, p in reversed(records):
        h2.add(v, t, p, 1.0)
    for seed in range(5):
        np.testing.assert_array_equal(
            h1.select(REF, 100.0, np.random.default_rng(seed)),
            h2.select(REF, 100.0, np.random.default_rng(seed)),
        )


# -- self-only filter, replacement, pruning, memory bound ---------------------------------------


def test_self_only_filter() -> None:
    h, _ = _forty()
    got = h.select_records(REF, 100.0, np.random.default_rng(0), vehicle_ids={"v1"})
    assert set(got.vehicle_ids) == {"v1"} and got.n_candidates == 10
    assert h.select(REF, 100.0, np.random.default_rng(0), vehicle_ids={"nobody"}).shape == (0, 3)
    both = h.select_records(REF, 100.0, np.random.default_rng(0), vehicle_ids=["v1", "v2"])
    assert set(both.vehicle_ids) == {"v1", "v2"} and both.n_candidates == 20


def test_same_vehicle_and_epoch_replaces() -> None:
    h = PositionHistory(CFG)
    h.add("a", 5.0, at(0, 0, 1), 1.0)
    h.add("a", 5.0 + 1e-5, at(200, 0, 1), 1.0)  # a smoother's update: moves to another cell
    h.add("b", 5.0, at(0, 0, 1), 1.0)
    assert len(h) == 2
    got = h.select_records(at(200, 0), 6.0, np.random.default_rng(0))
    assert got.vehicle_ids == ("a",)
    assert h.select_records(REF, 6.0, np.random.default_rng(0)).vehicle_ids == ("b",)


def test_pruning_keeps_memory_bounded_by_time() -> None:
    cfg = replace(CFG, max_history_s=10.0)
    h = PositionHistory(cfg)
    for t in range(100):
        h.add_many(["a", "b"], float(t), [at(t * 5.0, 0.0), at(t * 5.0, 3.5)], 1.5)
        assert len(h) <= 2 * (10 + 1 + 2)  # window + the auto-prune's slack of max_history_s / 8
    h.prune()
    got = h.select_records(at(99 * 5.0, 0), 100.0, np.random.default_rng(0))
    assert len(h) == 2 * 11  # t = 89 .. 99
    assert got.times_s.min() >= 90.0
    assert h.n_cells <= 3  # empty cells are dropped
    assert h.prune(1e6) == 22 and len(h) == 0 and h.n_cells == 0


def test_crowded_cell_is_capped_keeping_the_newest() -> None:
    cfg = replace(CFG, max_points_per_cell=40)
    h = PositionHistory(cfg)
    for t in range(200):
        h.add(f"v{t % 7}", float(t), at(1.0 + (t % 5), 1.0 + (t % 3), 1.0), 1.0)
        assert len(h) <= 50  # 1.25 x the cap
    assert h.n_cells == 1  # the premise: every point fell in one cell
    got = h.select_records(at(1.0, 1.0), 200.0, np.random.default_rng(0))
    assert got.n_candidates >= 40 and got.times_s.min() >= 200 - 50


def test_invalid_input_rejected_and_clear() -> None:
    h = PositionHistory(CFG)
    p = at(0, 0, 1)
    for bad in (
        lambda: h.add("a", math.nan, p, 1.0),
        lambda: h.add("a", 0.0, [math.nan, 0.0, 0.0], 1.0),
        lambda: h.add("a", 0.0, [0.0, 0.0, 0.0], 1.0),
        lambda: h.add("a", 0.0, p * 10, 1.0),
        lambda: h.add("a", 0.0, p, -0.5),
        lambda: h.add("", 0.0, p, 1.0),
        lambda: h.add_many(["a", "b"], 0.0, [p], 1.0),
        lambda: h.select([1.0, 2.0], 0.0, np.random.default_rng(0)),
    ):
        with pytest.raises(ValueError):
            bad()
    assert len(h) == 0
    h.add("a", 0.0, p, 1.0)
    assert len(h) == 1 and h.vehicle_ids == ("a",)
    h.clear()
    assert len(h) == 0 and h.vehicle_ids == () and h.n_cells == 0


def test_cell_keys_partition_space() -> None:
    assert cell_key([0.0, 49.9, -0.1], 50.0) == (0, 0, -1)
    assert cell_key([100.0, -100.0, 50.0], 50.0) == (2, -2, 1)
    road = project_to_road(at(3, 4, 1), 1.0)
    assert cell_key(road, 50.0) == tuple(int(c) for c in np.floor(road / 50.0))


def test_fleet_scale_query_visits_few_cells() -> None:
    """256 vehicles x 60 epochs spread over 4 km: answers match a full scan; ~27 cells per query."""
    rng = np.random.default_rng(3)
    h = PositionHistory(CFG)
    ids = [f"u{i:03d}" for i in range(256)]
    start = rng.uniform(-2000, 2000, (256, 2))
    for t in range(60):
        enu = np.c_[start + t * 10.0 * np.array([1.0, 0.3]), np.full(256, 1.5)]
        h.add_many(ids, float(t), enu_to_ecef(enu, REF), 1.5)
    assert len(h) == 256 * 60 and h.n_cells > 500
    big = replace(CFG, n_max=100000, max_points_per_cell=100000)
    full = PositionHistory(big)
    full._cells, full._vids, full._vid_index = h._cells, h._vids, h._vid_index  # same storage
    for _ in range(5):
        centre = enu_to_ecef(np.r_[start[rng.integers(256)] + 200.0, 1.5], REF)
        got = full.select_records(centre, 60.0, np.random.default_rng(0))
        assert len(full._buckets_near(centre, CFG.range_fitting_m)) <= 27
        all_pts = np.concatenate([b.xyz[: b.n][b.alive[: b.n]] for b in h._cells.values()])
        want = all_pts[np.linalg.norm(all_pts - centre, axis=1) < CFG.range_fitting_m]
        assert rows(got.points) == rows(want)
