"""GET /map/tiles and /map/changes (issue 14): the road map file served as GeoJSON, read-only."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient
from support.api import FLEET, SyntheticFleet

from coplane.api.app import create_app
from coplane.api.bus_client import LocalBus
from coplane.api.settings import ApiSettings
from coplane.geo import geodetic_to_ecef
from coplane.roadmap import ChangeEvent, TileKey, TilePlane, tile_of_ecef
from coplane.store.roadmap_db import RoadMapDb

LAT, LON = 22.2988, 114.1722


def _tile(key: TileKey) -> TilePlane:
    info = np.array([[4.0, 0.0, 0.0], [0.0, 30.0, 0.0], [0.0, 0.0, 30.0]])
    return TilePlane(
        key=key, h0_m=12.0, info=info, eta=np.array([0.8, 0.0, 0.0]), n_passes=4, n_points=8, version=4
    )


def _app(map_path: Path | None) -> TestClient:
    fleet = SyntheticFleet(n_vehicles=1, n_epochs=1)
    app = create_app(
        ApiSettings(fleet=FLEET, map=str(map_path) if map_path else None),
        LocalBus(),
        state=fleet.state(clock_now=0.0),
    )
    return TestClient(app)


@pytest.fixture
def map_file(tmp_path: Path) -> tuple[Path, list[TileKey]]:
    centre = tile_of_ecef(geodetic_to_ecef(math.radians(LAT), math.radians(LON), 10.0), 20.0)
    keys = [TileKey(centre.row + dr, centre.col + dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1)]
    far = TileKey(centre.row + 5000, centre.col)  # about 100 km north
    path = tmp_path / "map.sqlite"
    with RoadMapDb(path) as db:
        db.write([_tile(k) for k in [*keys, far]], [ChangeEvent(keys[0], 1.4e9, 11.5, 12.0, 3)])
    return path, keys


def test_tiles_in_a_box_as_geojson(map_file: tuple[Path, list[TileKey]]) -> None:
    path, keys = map_file
    d = 0.001  # about 110 m: the 3 x 3 tiles and not the far one
    with _app(path) as c:
        r = c.get("/map/tiles", params={"bbox": f"{LON - d},{LAT - d},{LON + d},{LAT + d}"})
        assert r.status_code == 200 and r.headers["content-type"].startswith("application/geo+json")
        fc = r.json()
        assert fc["type"] == "FeatureCollection" and len(fc["features"]) == len(keys)
        for f in fc["features"]:
            ring = f["geometry"]["coordinates"][0]
            assert f["geometry"]["type"] == "Polygon" and ring[0] == ring[-1] and len(ring) == 5
        changes = c.get("/map/changes", params={"limit": 5}).json()["changes"]
        assert [ch["tile"] for ch in changes] == [str(keys[0])]


@pytest.mark.parametrize(
    ("bbox", "says"),
    [
        ("1,2,3", "4 numbers"),
        ("a,b,c,d", "not numbers"),
        ("114,22,113,23", "min must be below max"),
        ("114,95,114.1,96", "latitudes"),
        ("114,22,116,23", "at most 0.5"),
        ("nan,22,114,23", "finite"),
    ],
)
def test_bad_boxes_are_422_naming_the_problem(
    map_file: tuple[Path, list[TileKey]], bbox: str, says: str
) -> None:
    with _app(map_file[0]) as c:
        r = c.get("/map/tiles", params={"bbox": bbox})
        assert r.status_code == 422 and says in r.text


def test_no_map_is_404_and_a_broken_one_503_without_stopping_the_api(tmp_path: Path) -> None:
    with _app(None) as c:
        r = c.get("/map/tiles", params={"bbox": "114,22,114.1,22.1"})
        assert r.status_code == 404 and "--map" in r.text
    with _app(tmp_path / "not-yet.sqlite") as c:  # the fusion server has not created it yet
        r = c.get("/map/tiles", params={"bbox": "114,22,114.1,22.1"})
        assert r.status_code == 404 and "does not exist yet" in r.text
    broken = tmp_path / "broken.sqlite"
    broken.write_bytes(b"not a database at all" * 100)
    with _app(broken) as c:
        r = c.get("/map/tiles", params={"bbox": "114,22,114.1,22.1"})
        assert r.status_code == 503 and "broken.sqlite" in r.text
        assert c.get("/map/changes").status_code == 503
        assert c.get("/healthz").status_code == 200  # the API goes on


def test_auto_serves_the_fusion_servers_default_map(
    map_file: tuple[Path, list[TileKey]], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Default `auto`: the map the fusion server keeps in the shared state directory (compose)."""
    state = tmp_path / "state"
    state.mkdir()
    monkeypatch.setenv("COPLANE_STATE_DIR", str(state))
    (state / f"map-{FLEET}.sqlite").write_bytes(map_file[0].read_bytes())
    fleet = SyntheticFleet(n_vehicles=1, n_epochs=1)
    app = create_app(ApiSettings(fleet=FLEET), LocalBus(), state=fleet.state(clock_now=0.0))
    d = 0.001
    with TestClient(app) as c:
        r = c.get("/map/tiles", params={"bbox": f"{LON - d},{LAT - d},{LON + d},{LAT + d}"})
        assert r.status_code == 200 and len(r.json()["features"]) == len(map_file[1])


def test_with_servers_by_region_a_server_s_replica_is_served(
    map_file: tuple[Path, list[TileKey]], tmp_path: Path
) -> None:
    """`map_server`: the named server's replica beside the map file (docs/scale.md), not the fleet
    file the servers only started from."""
    base = tmp_path / "fleet-map.sqlite"
    (tmp_path / "fleet-map.s1.sqlite").write_bytes(map_file[0].read_bytes())
    fleet = SyntheticFleet(n_vehicles=1, n_epochs=1)
    app = create_app(
        ApiSettings(fleet=FLEET, map=str(base), map_server="s1"), LocalBus(), state=fleet.state(clock_now=0.0)
    )
    with TestClient(app) as c:
        r = c.get("/map/tiles", params={"bbox": _box()})
        assert r.status_code == 200 and len(r.json()["features"]) == len(map_file[1])


def _box(d: float = 0.001) -> str:
    return f"{LON - d},{LAT - d},{LON + d},{LAT + d}"


def test_features_are_the_tiles_inside_with_their_numbers(map_file: tuple[Path, list[TileKey]]) -> None:
    path, keys = map_file
    with _app(path) as c:
        fc = c.get("/map/tiles", params={"bbox": _box()}).json()
        assert {f["id"] for f in fc["features"]} == {str(k) for k in keys}  # not the far tile
        for f in fc["features"]:
            p = f["properties"]
            assert p["tile"] == f["id"] and p["n_passes"] == 4 and p["version"] == 4 and p["changes"] == 0
            assert p["sigma_m"] > 0 and isinstance(p["usable"], bool) and math.isfinite(p["height_m"])
            ring = f["geometry"]["coordinates"][0]
            assert all(len(pt) == 2 and abs(pt[0] - LON) < 0.01 and abs(pt[1] - LAT) < 0.01 for pt in ring)
        # a box beside the mapped tiles: an empty collection, not an error
        far = c.get("/map/tiles", params={"bbox": f"{LON + 0.1},{LAT},{LON + 0.2},{LAT + 0.1}"}).json()
        assert far == {"type": "FeatureCollection", "features": []}


def test_boxes_the_grid_cannot_answer_are_422(
    map_file: tuple[Path, list[TileKey]], monkeypatch: pytest.MonkeyPatch
) -> None:
    from coplane.api.routers import map as road_map

    with _app(map_file[0]) as c:
        r = c.get("/map/tiles", params={"bbox": "10,85.5,10.1,85.6"})  # beyond the grid: not a 500
        assert r.status_code == 422 and "85" in r.json()["detail"]
        monkeypatch.setattr(road_map, "MAX_TILES", 4)
        r = c.get("/map/tiles", params={"bbox": _box()})
        assert r.status_code == 422 and "more than 4 stored tiles" in r.json()["detail"]
        monkeypatch.setattr(road_map, "MAX_ROWS", 2)
        r = c.get("/map/tiles", params={"bbox": _box()})
        assert r.status_code == 422 and "grid rows" in r.json()["detail"]
        r = c.get("/map/changes", params={"limit": 0})
        assert r.status_code == 422
        assert c.get("/map/changes", params={"limit": 1001}).status_code == 422


def test_reads_follow_a_concurrent_writer_without_blocking_it(map_file: tuple[Path, list[TileKey]]) -> None:
    """The map stays open for reading while the fusion server writes (WAL): new tiles show up on
    the next request, and a read during the writer's open transaction neither waits nor fails."""
    path, keys = map_file
    extra = TileKey(keys[0].row - 1, keys[0].col)  # just south of the 3 x 3 block, inside the box
    with _app(path) as c, RoadMapDb(path) as writer:
        assert len(c.get("/map/tiles", params={"bbox": _box()}).json()["features"]) == len(keys)
        writer.write([_tile(extra)], [ChangeEvent(extra, 1.5e9, 12.0, 12.6, 2)])
        fc = c.get("/map/tiles", params={"bbox": _box()}).json()
        assert str(extra) in {f["id"] for f in fc["features"]}
        assert c.get("/map/changes", params={"limit": 1}).json()["changes"][0]["tile"] == str(extra)
        writer.db.execute("BEGIN IMMEDIATE")  # the writer is in the middle of a batch
        writer.db.execute("DELETE FROM tiles")
        fc = c.get("/map/tiles", params={"bbox": _box()}).json()  # the last committed state
        assert len(fc["features"]) == len(keys) + 1
        writer.db.execute("ROLLBACK")
        writer.write([_tile(TileKey(extra.row - 1, extra.col))])  # and it can still commit
        metrics = c.get("/metrics").text
        assert 'coplane_api_map_requests_total{path="/map/tiles",status="200"} 3.0' in metrics
        assert "coplane_api_map_opens_total 1.0" in metrics  # one connection, kept


def test_a_replaced_or_broken_file_is_noticed_and_the_api_recovers(
    map_file: tuple[Path, list[TileKey]], tmp_path: Path
) -> None:
    path, keys = map_file
    served = tmp_path / "served.sqlite"
    served.write_bytes(path.read_bytes())
    with _app(served) as c:
        assert len(c.get("/map/tiles", params={"bbox": _box()}).json()["features"]) == len(keys)
        # replaced (a rebuilt map moved into place): the new file is served, not the old inode
        fresh = tmp_path / "fresh.sqlite"
        with RoadMapDb(fresh) as db:
            db.write([_tile(keys[4])])
        fresh.replace(served)
        fc = c.get("/map/tiles", params={"bbox": _box()}).json()
        assert [f["id"] for f in fc["features"]] == [str(keys[4])]
        # replaced by garbage: 503 naming the file, every other endpoint goes on
        junk = tmp_path / "junk"
        junk.write_bytes(b"\x00garbage" * 4096)
        junk.replace(served)
        r = c.get("/map/tiles", params={"bbox": _box()})
        assert r.status_code == 503 and "served.sqlite" in r.json()["detail"]
        assert c.get("/map/changes").status_code == 503
        assert c.get("/vehicles").status_code == 200 and c.get("/healthz").status_code == 200
        # removed: "not there yet" again; a good map put back: served again
        served.unlink()
        assert c.get("/map/tiles", params={"bbox": _box()}).status_code == 404
        served.write_bytes(path.read_bytes())
        assert len(c.get("/map/tiles", params={"bbox": _box()}).json()["features"]) == len(keys)
        metrics = c.get("/metrics").text
        assert 'coplane_api_map_requests_total{path="/map/tiles",status="503"} 1.0' in metrics
        assert 'coplane_api_map_requests_total{path="/map/changes",status="503"} 1.0' in metrics
        assert 'coplane_api_map_requests_total{path="/map/tiles",status="404"} 1.0' in metrics
