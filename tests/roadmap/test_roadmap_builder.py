"""The builder: trust filter, de-mapping, and grouping samples into passes."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import Road

from coplane.geo import ecef_to_geodetic, enu_rotation, up_vector
from coplane.plane.history import project_to_road
from coplane.roadmap import MapBuilder, MapSample, RoadMap, RoadMapConfig, tile_frame, tile_of_ecef

CFG = RoadMapConfig()
ANT = 1.6


def cov_enu(road: Road, p: np.ndarray, sig_e: float, sig_n: float, sig_u: float) -> np.ndarray:
    lat, lon, _ = ecef_to_geodetic(p)
    r = enu_rotation(float(lat), float(lon))
    return r.T @ np.diag([sig_e**2, sig_n**2, sig_u**2]) @ r


def drive(
    road: Road,
    vid: str,
    t0: float,
    e0: float,
    n: float,
    speed: float,
    dur: float,
    dh: float = 0.0,
    sig_u: float = 0.3,
) -> list[MapSample]:
    """10 Hz samples of a vehicle driving east at `speed`, `dh` above its true antenna height."""
    dt = 0.1
    out = []
    for k in range(round(dur / dt)):
        e = e0 + speed * k * dt
        p = road.antenna_ecef(e, n, ANT, dh)
        out.append(MapSample(vid, t0 + k * dt, p, cov_enu(road, p, 0.5, 0.5, sig_u), ANT))
    return out


def test_consecutive_samples_in_a_tile_form_one_pass(road: Road) -> None:
    b = MapBuilder(CFG)
    for s in drive(road, "v1", 1000.0, -30.0, 1.0, 10.0, 6.0):  # 60 m east at 10 m/s
        b.add(s)
    passes = b.flush()
    assert 3 <= len(passes) <= 5 and sum(len(p.points_enu) for p in passes) == 60
    assert [p.time_s for p in passes] == sorted(p.time_s for p in passes)
    assert len({p.key for p in passes}) == len(passes)  # one pass per tile here
    for p in passes:
        assert p.key is not None and p.h_ref_m == 0.0 and p.vehicle_id == "v1"
        origin, rot = tile_frame(p.key, CFG.tile_size_m)
        for e, n, u in p.points_enu:  # every point lies in its pass's tile
            q = origin + rot.T @ np.array([e, n, u])
            assert tile_of_ecef(q, CFG.tile_size_m) == p.key
            # u is the road's ellipsoidal height (to the frame's curvature)
            assert u == pytest.approx(float(ecef_to_geodetic(q)[2]), abs=1e-4)
        np.testing.assert_allclose(p.sigmas_up_m, 0.3)
    assert b.flush() == [] and dict(b.skipped) == {}


def test_a_gap_splits_a_pass_and_silence_closes_it(road: Road) -> None:
    b = MapBuilder(CFG)
    p = road.antenna_ecef(0.0, 0.0, ANT)
    c = cov_enu(road, p, 0.5, 0.5, 0.3)
    for t in (0.0, 1.0, 2.0, 6.0, 7.0):  # 4 s > pass_gap_s: a second pass in the same tile
        b.add(MapSample("v1", t, p, c, ANT))
    ready = b.passes_ready()  # the gap closed the first pass; the second is still open
    assert [(q.vehicle_id, len(q.points_enu), q.time_s) for q in ready] == [("v1", 3, 2.0)]
    b.add(MapSample("v2", 20.0, p, c, ANT))  # v1 silent for 13 s: its open pass is closed
    ready = b.passes_ready()
    assert [(q.vehicle_id, len(q.points_enu), q.time_s) for q in ready] == [("v1", 2, 7.0)]
    assert b.passes_ready() == []  # forgotten once returned
    rest = b.flush()
    assert [(q.vehicle_id, len(q.points_enu)) for q in rest] == [("v2", 1)]


def test_passes_do_not_depend_on_interleaving(road: Road) -> None:
    a = drive(road, "a", 0.0, -25.0, 1.5, 8.0, 5.0)
    b = drive(road, "b", 0.05, -25.0, -1.5, 9.0, 5.0)
    m1, m2 = MapBuilder(CFG), MapBuilder(CFG)
    for s in sorted(a + b, key=lambda s: (s.time_s, s.vehicle_id)):
        m1.add(s)
    for s in a + b:  # all of a first, then all of b
        m2.add(s)
    p1, p2 = m1.flush(), m2.flush()
    assert [(p.time_s, p.vehicle_id, p.key) for p in p1] == [(p.time_s, p.vehicle_id, p.key) for p in p2]
    for x, y in zip(p1, p2, strict=True):
        np.testing.assert_array_equal(x.points_enu, y.points_enu)


def test_trust_filter_counts_rejections_by_reason(road: Road) -> None:
    b = MapBuilder(CFG)
    p = road.antenna_ecef(0.0, 0.0, ANT)
    good = cov_enu(road, p, 0.5, 0.5, 0.3)
    b.add(MapSample("v", 0.0, p, good, ANT))
    b.add(MapSample("v", 0.1, p, None, ANT))
    b.add(MapSample("v", 0.2, p, cov_enu(road, p, 0.5, 0.5, 3.5), ANT))
    b.add(MapSample("v", 0.3, p, cov_enu(road, p, 0.5, 3.2, 0.3), ANT))
    b.add(MapSample("v", 0.4, p, good, ANT, has_gnss_fix=False))
    b.add(MapSample("v", 0.5, p, good, ANT, flagged=True))
    b.add(MapSample("v", 0.6, np.array([math.nan, 0.0, 0.0]), good, ANT))
    b.add(MapSample("v", 0.7, p, np.full((3, 3), math.nan), ANT))
    assert dict(b.skipped) == {
        "no-covariance": 2,
        "sigma-up": 1,
        "sigma-h": 1,
        "no-fix": 1,
        "flagged": 1,
        "not-finite": 1,
    }
    assert [len(q.points_enu) for q in b.flush()] == [1]


def test_demapping_removes_the_maps_own_information(road: Road) -> None:
    """A solution fused with the map's plane: the builder keeps only the GNSS's own height."""
    b = MapBuilder(CFG)
    p_g = road.antenna_ecef(2.0, 1.0, ANT, dh=0.4)  # what GNSS alone said: 0.4 m high, sigma 0.5
    s_g, s_p, h_p_off = 0.5, 0.2, -0.1  # the map plane said 0.1 m low, sigma 0.2
    h_true = float(ecef_to_geodetic(road.antenna_ecef(2.0, 1.0, ANT))[2])
    var_f = 1.0 / (1 / s_g**2 + 1 / s_p**2)
    h_f = var_f * ((h_true + 0.4) / s_g**2 + (h_true + h_p_off) / s_p**2)  # the fused height
    up = up_vector(p_g)
    p_f = p_g + (h_f - (h_true + 0.4)) * up
    b.add(
        MapSample(
            "v",
            0.0,
            p_f,
            cov_enu(road, p_f, 0.3, 0.3, math.sqrt(var_f)),
            ANT,
            map_plane_sigma_m=s_p,
            map_plane_height_m=h_true + h_p_off,
        )
    )
    (pa,) = b.flush()
    road_h = float(ecef_to_geodetic(project_to_road(p_g, ANT))[2])
    # the GNSS height, not the fused one (to the tile frame's curvature, < 20 um)
    assert pa.points_enu[0, 2] == pytest.approx(road_h, abs=1e-4)
    assert pa.sigmas_up_m[0] == pytest.approx(s_g, rel=1e-9)
    # a solution that is nearly all map carries no independent evidence: skipped
    b.add(
        MapSample(
            "v",
            1.0,
            p_f,
            cov_enu(road, p_f, 0.3, 0.3, 0.1999),
            ANT,
            map_plane_sigma_m=0.2,
            map_plane_height_m=h_true,
        )
    )
    assert b.flush() == [] and b.skipped["self-mapped"] == 1


def test_builder_to_map_learns_the_road(road: Road) -> None:
    rng = np.random.default_rng(3)
    b = MapBuilder(CFG)
    samples = []
    for k in range(12):  # 12 drives over the same 40 m in two lanes, each with its own error
        lane = 1.75 * (-1) ** k
        samples += drive(
            road, f"v{k % 3}", 100.0 * k, -20.0, lane, 10.0, 4.0, dh=rng.normal(0, 0.2), sig_u=0.2
        )
    for sample in samples:
        b.add(sample)
    road_map = RoadMap(CFG)
    assert road_map.apply(b.flush()) == []
    assert road_map.stats()["usable_tiles"] >= 2
    for tile in road_map.tiles.values():
        if tile.n_passes < 10:
            continue
        origin, rot = tile_frame(tile.key, CFG.tile_size_m)
        for e, n in ((0.0, 0.0), (5.0, 2.0)):
            lat, lon, _ = ecef_to_geodetic(origin + rot.T @ np.array([e, n, 0.0]))
            # the true road height at that horizontal position
            h_true = _true_height_at(road, float(lat), float(lon))
            h, s = tile.height_at(e, n, CFG)
            assert abs(h - h_true) < 3 * s, (tile.key, h - h_true, s)


def _true_height_at(road: Road, lat: float, lon: float) -> float:
    from coplane.geo import ecef_to_enu, geodetic_to_ecef

    e, n, _ = ecef_to_enu(geodetic_to_ecef(lat, lon, 0.0), geodetic_to_ecef(road.lat0, road.lon0, 0.0))
    return road.height(float(e), float(n))
