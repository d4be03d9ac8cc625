"""RoadMap: applying passes, serving planes (and their sign convention), pickling, GeoJSON."""

from __future__ import annotations

import dataclasses
import itertools
import json
import math
import pickle

import numpy as np
import pytest
from conftest import Road

from coplane.geo import up_vector
from coplane.plane.fit import constraint_error
from coplane.plane.history import project_to_road
from coplane.roadmap import (
    MapBuilder,
    MapSample,
    PassEvidence,
    RoadMap,
    RoadMapConfig,
    TilePlane,
    tile_frame,
    tile_of_ecef,
    tiles_geojson,
)

CFG = RoadMapConfig()
ANT = 1.5


def passes_over(
    road: Road, n_passes: int, rng: np.random.Generator, sigma: float = 0.1
) -> list[PassEvidence]:
    """Drives in two lanes over 60 m of the road, each with one error of `sigma`."""
    b = MapBuilder(CFG)
    for k in range(n_passes):
        dh = float(rng.normal(0.0, sigma))
        lane = 1.75 if k % 2 else -1.75
        for j in range(30):
            e = -30.0 + 2.0 * j
            p = road.antenna_ecef(e, lane, ANT, dh)
            b.add(MapSample(f"v{k % 3}", 60.0 * k + 0.2 * j, p, np.diag([0.04, 0.04, sigma**2]), ANT))
    return b.flush()


def built(road: Road, n_passes: int = 12) -> RoadMap:
    m = RoadMap(CFG)
    m.apply(passes_over(road, n_passes, np.random.default_rng(5)))
    return m


def test_plane_at_sign_convention_and_height(road: Road) -> None:
    m = built(road)
    antenna = road.antenna_ecef(3.0, 1.0, ANT)
    plane = m.plane_at(antenna, ANT)
    assert plane is not None
    road_pt = road.road_ecef(3.0, 1.0)
    assert (
        plane.key == tile_of_ecef(road_pt, CFG.tile_size_m) and plane.n_passes == m.tiles[plane.key].n_passes
    )
    assert (
        np.linalg.norm(plane.normal) == pytest.approx(1.0) and float(plane.normal @ up_vector(road_pt)) > 0.99
    )
    assert plane.d_antenna == plane.d_road - ANT
    # a point h above the (mapped) road surface along the normal: error h - antenna height
    surface = road_pt - (float(plane.normal @ road_pt) + plane.d_road) * plane.normal
    for h in (0.0, 0.7, ANT, 2.5):
        err = constraint_error(plane.normal, plane.d_antenna, surface + h * plane.normal)
        assert err == pytest.approx(h - ANT, abs=1e-6)
    # the mapped surface is the true road to within its sigma
    assert abs(float(plane.normal @ road_pt) + plane.d_road) < 3 * plane.sigma_m
    assert CFG.roughness_sigma_m <= plane.sigma_m <= CFG.max_use_sigma_m
    assert 0.0 < plane.offset_sigma_m < plane.sigma_m and 0.0 < plane.tilt_sigma_rad < CFG.slope_prior_sigma
    # the true grade is 3 % east, -1 % north: the normal leans west (and a little north)
    _, rot = tile_frame(plane.key, CFG.tile_size_m)
    n_enu = rot @ plane.normal
    assert n_enu[0] == pytest.approx(-0.03, abs=0.01) and n_enu[1] == pytest.approx(0.01, abs=0.03)
    assert plane.version == m.tiles[plane.key].version
    again = m.plane_at(antenna, ANT)
    assert again is not None and again.normal is plane.normal  # cached by tile version


def test_plane_at_refuses_unknown_thin_or_vague_tiles(road: Road) -> None:
    m = built(road, n_passes=1)
    antenna = road.antenna_ecef(0.0, 1.75, ANT)
    assert m.tile_at(project_to_road(antenna, ANT)) is not None
    assert m.plane_at(antenna, ANT) is None  # one pass: not usable
    far = road.antenna_ecef(500.0, 0.0, ANT)
    assert m.plane_at(far, ANT) is None and m.tile_at(far) is None
    m2 = built(road, n_passes=4)
    assert m2.plane_at(antenna, ANT) is not None
    strict = RoadMap(dataclasses.replace(CFG, max_use_sigma_m=0.06), m2.tiles)
    assert strict.plane_at(antenna, ANT) is None  # sigma at the vehicle above the limit


def test_a_plane_reflects_a_tile_update(road: Road) -> None:
    m = built(road, n_passes=4)
    antenna = road.antenna_ecef(0.0, 1.75, ANT)
    before = m.plane_at(antenna, ANT)
    m.apply(passes_over(road, 2, np.random.default_rng(9)))
    after = m.plane_at(antenna, ANT)
    assert before is not None and after is not None and after.version > before.version
    assert after.n_passes == before.n_passes + 2


def test_apply_is_order_independent_and_tracks_dirty_tiles(road: Road) -> None:
    passes = passes_over(road, 8, np.random.default_rng(1))
    a, b = RoadMap(CFG), RoadMap(CFG)
    a.apply(passes)
    b.apply(list(reversed(passes)))
    assert a.tiles.keys() == b.tiles.keys()
    for k in a.tiles:
        np.testing.assert_array_equal(a.tiles[k].info, b.tiles[k].info)
        np.testing.assert_array_equal(a.tiles[k].eta, b.tiles[k].eta)
        assert a.tiles[k].h0_m == b.tiles[k].h0_m
    dirty = a.take_dirty()
    assert [t.key for t in dirty] == sorted(a.tiles) and a.take_dirty() == []
    one = [p for p in passes if p.key == dirty[0].key][:1]
    a.apply(one)
    assert [t.key for t in a.take_dirty()] == [dirty[0].key]
    with pytest.raises(ValueError, match="no tile key"):
        a.apply([PassEvidence("v", 0.0, np.zeros((1, 3)), np.ones(1))])


def test_new_tile_h0_is_the_first_pass_mean_height(road: Road) -> None:
    m = built(road, n_passes=1)
    for tile in m.tiles.values():
        (first,) = tile.recent  # equal sigmas: its weighted mean height is its mean, 0 above h0
        assert first.accepted and abs(first.eta[0] / first.info[0, 0]) < 1e-9
        assert 500.0 < tile.h0_m < 540.0


def test_stats_and_pickle(road: Road) -> None:
    m = built(road)
    s = m.stats()
    assert s["tiles"] == len(m.tiles) and s["usable_tiles"] >= 3 and s["passes"] >= 12 and s["changes"] == 0
    antenna = road.antenna_ecef(3.0, 1.0, ANT)
    m.plane_at(antenna, ANT)
    m2 = pickle.loads(pickle.dumps(m))
    assert m2.stats() == s and m2.config == m.config
    p1, p2 = m.plane_at(antenna, ANT), m2.plane_at(antenna, ANT)
    assert p1 is not None and p2 is not None
    np.testing.assert_array_equal(p1.normal, p2.normal)
    assert (p1.d_road, p1.sigma_m) == (p2.d_road, p2.sigma_m)


def test_geojson_is_strict_json_with_the_properties(road: Road) -> None:
    m = built(road)
    empty = TilePlane(tile_of_ecef(road.road_ecef(900.0, 0.0), CFG.tile_size_m), 500.0)
    fc = tiles_geojson([*m.tiles.values(), empty], CFG)
    text = json.dumps(fc, allow_nan=False)  # no NaN, no numpy types
    assert json.loads(text) == fc
    assert fc["type"] == "FeatureCollection" and len(fc["features"]) == len(m.tiles) + 1
    for f in fc["features"]:
        ring = f["geometry"]["coordinates"][0]
        assert f["type"] == "Feature" and f["geometry"]["type"] == "Polygon"
        assert len(ring) == 5 and ring[0] == ring[-1]
        area2 = sum(x0 * y1 - x1 * y0 for (x0, y0), (x1, y1) in itertools.pairwise(ring))
        assert area2 > 0  # counter-clockwise exterior ring (RFC 7946)
    props = {f["properties"]["tile"]: f["properties"] for f in fc["features"]}
    e = props[str(empty.key)]
    assert e["height_m"] is None and e["sigma_m"] is None and e["usable"] is False and e["n_passes"] == 0
    key, tile = next((k, t) for k, t in m.tiles.items() if t.usable(CFG))
    p = props[str(key)]
    h, s = tile.height_at(0.0, 0.0, CFG)
    assert (p["height_m"], p["sigma_m"]) == (h, s) and p["usable"] is True
    assert p["grade_east"] == pytest.approx(0.03, abs=0.02) and p["grade_north"] == pytest.approx(
        -0.01, abs=0.05
    )
    assert set(p) == {
        "tile", "height_m", "sigma_m", "grade_east", "grade_north", "slope_sigma", "n_passes",
        "outlier_passes", "changes", "version", "updated_s", "usable",
    }  # fmt: skip
    assert math.isfinite(p["slope_sigma"])


def test_a_tile_without_a_sound_plane_never_reaches_the_graph(road: Road) -> None:
    """plane_at gives None, counted, for a tile whose numbers do not make a plane (one that slipped
    past the file's and the bus's checks, or was damaged in memory)."""
    m = built(road)
    antenna = road.antenna_ecef(3.0, 1.0, ANT)
    plane = m.plane_at(antenna, ANT)
    assert plane is not None
    tile = m.tiles[plane.key]
    m.tiles[plane.key] = dataclasses.replace(tile, info=np.zeros((3, 3)), version=tile.version + 1)
    assert m.plane_at(antenna, ANT) is None and m.rejected["tile without a plane"] == 1
    m.tiles[plane.key] = dataclasses.replace(tile, eta=np.array([np.nan, 0.0, 0.0]), version=tile.version + 2)
    assert m.plane_at(antenna, ANT) is None and sum(m.rejected.values()) == 2


def test_plane_at_refuses_singular_and_not_positive_definite_information(road: Road) -> None:
    """Information that is singular with the slope prior, or invertible but not positive definite
    (how a negative sigma looks in information form), gives no plane; the sound tile again does."""
    m = built(road)
    antenna = road.antenna_ecef(3.0, 1.0, ANT)
    plane = m.plane_at(antenna, ANT)
    assert plane is not None
    tile = m.tiles[plane.key]
    p = 1.0 / CFG.slope_prior_sigma**2
    singular = np.diag([1.0, -p, 0.0])  # info + prior = diag(1, 0, p)
    m.tiles[plane.key] = dataclasses.replace(tile, info=singular, version=tile.version + 1)
    assert m.plane_at(antenna, ANT) is None
    assert m.rejected == {"tile without a plane": 1}
    # invertible, every sigma at the vehicle looks fine, yet one direction has negative variance
    not_pd = np.diag([1.0, -2.0 * p, 0.0])
    m.tiles[plane.key] = dataclasses.replace(tile, info=not_pd, version=tile.version + 2)
    assert tile.problem(CFG) is None and m.tiles[plane.key].problem(CFG) is not None
    assert m.plane_at(antenna, ANT) is None
    assert m.rejected["information matrix not positive definite"] == 1
    m.tiles[plane.key] = tile
    again = m.plane_at(antenna, ANT)
    assert again is not None and again.d_road == plane.d_road and sum(m.rejected.values()) == 2


@pytest.mark.parametrize(
    ("patch", "reason"),
    [
        ("double normal", "normal not a unit vector"),
        ("downward normal", "normal not upward"),
        ("nan d_road", "non-finite plane"),
        ("negative sigma", "sigma not a positive number"),
        ("zero sigma", "sigma not a positive number"),
        ("nan sigma", "sigma not a positive number"),
    ],
)
def test_plane_at_refuses_an_unsound_plane(
    road: Road, monkeypatch: pytest.MonkeyPatch, patch: str, reason: str
) -> None:
    """Whatever the tile's numbers, a plane that is not unit, upward, finite with a positive sigma
    never reaches the graph: None, counted by reason."""
    m = built(road)
    antenna = road.antenna_ecef(3.0, 1.0, ANT)
    assert m.plane_at(antenna, ANT) is not None
    plane_ecef, sigma_at = TilePlane.plane_ecef, TilePlane.sigma_at_ecef

    def bad_plane(self: TilePlane, config: RoadMapConfig) -> tuple[np.ndarray, float]:
        n, d = plane_ecef(self, config)
        if patch == "double normal":
            return 2.0 * n, d
        if patch == "downward normal":
            return -n, -d
        return n, (math.nan if patch == "nan d_road" else d)

    def bad_sigma(self: TilePlane, p: object, config: RoadMapConfig) -> float:
        s = sigma_at(self, p, config)  # type: ignore[arg-type]
        return {"negative sigma": -s, "zero sigma": 0.0, "nan sigma": math.nan}.get(patch, s)

    monkeypatch.setattr(TilePlane, "plane_ecef", bad_plane)
    monkeypatch.setattr(TilePlane, "sigma_at_ecef", bad_sigma)
    fresh = RoadMap(CFG, m.tiles)  # no cached plane
    assert fresh.plane_at(antenna, ANT) is None
    assert fresh.rejected == {reason: 1}


def test_geojson_of_a_tile_without_a_sound_plane_has_null_numbers(road: Road) -> None:
    """A viewer (map show, the API) shows a damaged tile without its numbers instead of failing."""
    m = built(road)
    key, tile = next(iter(m.tiles.items()))
    p = 1.0 / CFG.slope_prior_sigma**2
    bad = dataclasses.replace(tile, info=np.diag([1.0, -p, 0.0]))
    fc = tiles_geojson([bad], CFG)
    props = fc["features"][0]["properties"]
    assert props["tile"] == str(key) and props["height_m"] is None and props["sigma_m"] is None
    json.dumps(fc, allow_nan=False)
