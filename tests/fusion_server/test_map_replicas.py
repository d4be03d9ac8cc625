"""The road map across fusion servers (docs/scale.md, "The road map across servers"): each server
writes only the tiles of its own regions, keeps the others' from the bus in its own file, and
starts from a copy of the fleet's map."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from coplane.bus import encode
from coplane.fusion_server.road_map import LiveRoadMap, server_map
from coplane.messages import DiagnosticsMessage, MapTilesMessage
from coplane.roadmap import MapSample, PassEvidence, RoadMapConfig, TileKey, TilePlane
from coplane.steps.map_tiles import MapReceiver, tiles_messages
from coplane.store.roadmap_db import RoadMapDb

CFG = RoadMapConfig()


def _tile(col: int, version: int = 3) -> TilePlane:
    info = np.diag([40.0, 300.0, 300.0])
    return TilePlane(
        key=TileKey(100, col), h0_m=41.5, info=info, eta=np.array([4.0, 0.0, 0.0]),
        n_passes=4, n_points=40, version=version, updated_s=1.4e9,
    )  # fmt: skip


def _pass(col: int, vid: str, t: float, dh: float) -> PassEvidence:
    e = np.linspace(-8.0, 8.0, 9)
    pts = np.column_stack([e, np.zeros_like(e), np.full_like(e, 0.1 + dh)])
    return PassEvidence(vid, t, pts, np.full(len(e), 0.3), key=TileKey(100, col))


def _even_cols(key: TileKey, _size: float) -> bool:
    return key.col % 2 == 0


def _odd_cols(key: TileKey, _size: float) -> bool:
    return key.col % 2 == 1


def _base(tmp_path: Path) -> Path:
    base = tmp_path / "map-f1.sqlite"
    with RoadMapDb(base) as db:
        db.write([_tile(0), _tile(1)])
    return base


def test_each_server_starts_from_a_copy_of_the_fleet_map(tmp_path: Path) -> None:
    base = _base(tmp_path)
    p1 = server_map(base, "s1")
    assert p1.name == "map-f1.s1.sqlite" and p1.is_file()
    with RoadMapDb(p1, readonly=True) as db:
        assert set(db.load().tiles) == {TileKey(100, 0), TileKey(100, 1)}
    with RoadMapDb(p1) as db:  # the server's own file is its own from then on
        db.write([_tile(2)])
    assert server_map(base, "s1") == p1
    with RoadMapDb(p1, readonly=True) as db:
        assert len(db.load().tiles) == 3
    # no fleet map: an empty file; a base that is no map: logged, an empty file, no exception
    assert not server_map(tmp_path / "none.sqlite", "s1").exists()
    junk = tmp_path / "junk.sqlite"
    junk.write_bytes(b"not a database" * 100)
    p = server_map(junk, "s2")
    assert not p.exists() and not p.with_name(p.name + ".tmp").exists()


def test_a_server_writes_its_own_tiles_and_takes_the_others(tmp_path: Path) -> None:
    base = _base(tmp_path)
    a = LiveRoadMap(server_map(base, "s1"), {}, fleet="f1", server="s1", owns_tile=_even_cols)
    b = LiveRoadMap(server_map(base, "s2"), {}, fleet="f1", server="s2", owns_tile=_odd_cols)
    a.take_outbox(), b.take_outbox()  # the start snapshots
    a._commit([_pass(0, "v1", 1.5e9, 0.2), _pass(1, "v2", 1.5e9, 0.2)])
    assert a.counts["foreign-tile"] == 1 and a.counts["passes_added"] == 1
    assert a.map.tiles[TileKey(100, 0)].version == 4 and a.map.tiles[TileKey(100, 1)].version == 3
    out = a.take_outbox()
    assert [m.server for m in out] == ["s1"] and [t.tile for t in out[0].tiles] == ["r100c0"]
    # b takes a's tile, in memory and in its file; a skips its own batch
    assert b.take_peer(encode(out[0])) == 1
    assert a.take_peer(encode(out[0])) == 0
    assert b.map.tiles[TileKey(100, 0)].version == 4
    assert b.take_peer(encode(out[0])) == 0 and b.counts["peer-older"] == 1  # a repeat
    b.close()
    with RoadMapDb(tmp_path / "map-f1.s2.sqlite", readonly=True) as db:
        assert db.load().tiles[TileKey(100, 0)].version == 4
    # garbage, another fleet, a bad tile: counted, nothing else happens
    assert a.take_peer(b"{not json") == 0 and a.counts["peer-rejected:invalid-json"] == 1
    other = tiles_messages("f2", [_tile(1, 9)], CFG, 1, False, "s2")[0]
    assert a.take_peer(encode(other)) == 0
    bad = _tile(1, 9)
    bad.info[1, 1] = -500.0
    assert a.take_peer(encode(tiles_messages("f1", [bad], CFG, 1, False, "s2")[0])) == 0
    assert a.counts["peer-rejected:information matrix not positive definite"] == 1
    a.close()


def test_diagnostics_report_the_fleets_common_residual_against_the_map(tmp_path: Path) -> None:
    m = LiveRoadMap(_base(tmp_path), {}, fleet="f1")
    assert m.diagnostics() == {}
    # 40 passes, a second apart, 0.2 m above both tiles: the tiles follow, the residuals shrink
    m._commit([_pass(k % 2, f"v{k % 3}", 1.5e9 + k, 0.2) for k in range(40)])
    d = m.diagnostics()
    assert d["map_common_passes"] == 39 and 0.0 < d["map_common_offset_m"] <= 0.2 + 1e-9
    assert d["map_counts"] == {"passes_added": 40}
    DiagnosticsMessage(fleet="f1", method="pc", pace="lockstep", epochs_solved=1, **d)  # fits the wire
    m.close()


def test_diagnostics_say_why_the_map_learns_nothing(tmp_path: Path) -> None:
    """Samples the trust filter skips (a standalone fleet: sigma-up) are counted by reason in the
    diagnostics, not only in the log at close."""
    m = LiveRoadMap(_base(tmp_path), {}, fleet="f1")
    p = np.array([-2418077.0, 5386069.0, 2405174.0])
    wide = 25.0 * np.eye(3)  # 5 m sigma: above max_sigma_up_m (tested before the horizontal one)
    for k in range(3):
        m.builder.add(MapSample("v1", 1.5e9 + k, p, wide, 1.5, True))
    assert m.diagnostics()["map_counts"] == {"skipped:sigma-up": 3}
    m.close()


def test_snapshot_parts_are_counted_per_server() -> None:
    """Every server numbers its snapshots from 1: parts of two servers' snapshot 1 are not one."""

    def part(server: str, i: int) -> MapTilesMessage:
        return MapTilesMessage(
            fleet="f1", server=server, tile_size_m=20.0, snapshot=1, part=i, parts=3, tiles=[]
        )

    rx = MapReceiver("f1")
    for m in (part("s1", 0), part("s1", 1), part("s2", 2)):
        rx.take(m)
    assert not rx.complete
    rx.take(part("s1", 2))
    assert rx.complete


def test_a_map_plane_is_checkable_without_an_spp_fix() -> None:
    """A map plane carries the tile centre as its centroid: the server's plausibility check can
    test it when the vehicle has no SPP fix (before, it rejected the whole node message)."""
    from types import SimpleNamespace

    from coplane.fusion_server.plausibility import plane_problem
    from coplane.geo import geodetic_to_ecef, up_vector
    from coplane.roadmap import RoadMap, tile_of_ecef
    from coplane.steps.wire import map_plane_report

    road = geodetic_to_ecef(np.radians(35.0), np.radians(137.0), 41.5)
    key = tile_of_ecef(road, CFG.tile_size_m)
    tile = TilePlane(
        key=key,
        h0_m=41.5,
        info=np.diag([40.0, 300.0, 300.0]),
        eta=np.zeros(3),
        n_passes=4,
        n_points=40,
        version=1,
    )
    road_map = RoadMap(CFG)
    road_map.tiles[key] = tile
    plane = road_map.plane_at(road + 1.5 * up_vector(road), 1.5)
    assert plane is not None
    report = map_plane_report(plane)
    assert report.centroid_ecef_m is not None
    msg = SimpleNamespace(plane=report, spp=SimpleNamespace(position_ecef_m=None))
    assert plane_problem(msg, 10.0, 50.0) is None  # type: ignore[arg-type]


def test_only_a_tiles_writer_is_believed_about_it(tmp_path: Path) -> None:
    """A snapshot carries the sender's replicas of others' tiles too: a server takes from it only
    the tiles the sender writes, so no server overwrites the tiles another writes (not even with a
    higher version); within the grace time after the servers changed (None) it takes them all."""

    def writers(key: TileKey, _size: float) -> set[str] | None:
        return {"s1"} if key.col % 2 == 0 else {"s2"}

    base = _base(tmp_path)
    b = LiveRoadMap(
        server_map(base, "s2"), {}, fleet="f1", server="s2", owns_tile=_odd_cols, tile_writers=writers
    )
    snap = tiles_messages("f1", [_tile(0, 7), _tile(1, 9)], CFG, 2, True, "s1")[0]
    assert b.take_peer(encode(snap)) == 1 and b.counts["peer-not-writer"] == 1
    assert b.map.tiles[TileKey(100, 0)].version == 7 and b.map.tiles[TileKey(100, 1)].version == 3
    # both wrote tile 0 across a move and reached version 7: the writer's copy wins, a repeat of
    # the copy it already has does not count again
    other = _tile(0, 7)
    other.eta[0] = 5.0
    b.map.tiles[TileKey(100, 0)] = other
    assert b.take_peer(encode(snap)) == 1 and b.counts["peer-conflict"] == 1
    assert b.map.tiles[TileKey(100, 0)].eta[0] == 4.0
    assert b.take_peer(encode(snap)) == 0 and b.counts["peer-conflict"] == 1
    b.tile_writers = lambda _key, _size: None  # the grace time after a change of the servers
    assert b.take_peer(encode(snap)) == 1 and b.map.tiles[TileKey(100, 1)].version == 9
    b.close()


def test_a_batch_is_believed_only_from_the_server_its_key_names(tmp_path: Path) -> None:
    """The router's ACL ties a server's tiles key, `map/tiles/<id>`, to its own certificate;
    the batch's `server` field is what the sender says. A batch whose field names another server
    than its key (a server speaking for another) is dropped whole, by servers and agents alike."""
    base = _base(tmp_path)
    b = LiveRoadMap(server_map(base, "s2"), {}, fleet="f1", server="s2", owns_tile=_odd_cols)
    b.take_outbox()
    says_s1 = tiles_messages("f1", [_tile(0, 9)], CFG, 1, False, "s1")[0]
    assert b.take_peer(encode(says_s1), "s3") == 0 and b.counts["peer-rejected:wrong-sender"] == 1
    assert b.map.tiles[TileKey(100, 0)].version == 3
    assert b.take_peer(encode(says_s1), "s1") == 1  # from the key it names: taken
    b.close()
    rx = MapReceiver("f1")
    assert rx.take(says_s1, "s3") == 0 and rx.counts["rejected:wrong-sender"] == 1
    assert rx.take(says_s1, "") == 0  # the single server's key names no server
    assert rx.take(says_s1, "s1") == 1 and rx.map.tiles[TileKey(100, 0)].version == 9


def test_a_region_server_passes_each_batch_the_server_its_key_names(tmp_path: Path) -> None:
    """The server's dispatch: a tiles batch from `map/tiles/<id>` reaches the replica with that
    sender, so one naming another server than its key is dropped there."""
    from coplane.bus import Payload
    from coplane.fusion_server.server import FusionServer
    from coplane.fusion_server.settings import FusionSettings
    from coplane.sim import ensure_default_recording

    server = FusionServer(
        FusionSettings(
            recording=ensure_default_recording(), db="none", map="none", regions=True, server_id="s2"
        )
    )
    server.road_map = LiveRoadMap(server_map(_base(tmp_path), "s2"), {}, fleet=server.fleet, server="s2")
    says_s1 = tiles_messages(server.fleet, [_tile(0, 9)], CFG, 1, False, "s1")[0]
    server.handle(Payload(server.keys.server_tiles("s3"), encode(says_s1)))
    assert server.road_map.counts["peer-rejected:wrong-sender"] == 1
    server.handle(Payload(server.keys.server_tiles("s1"), encode(says_s1)))
    assert server.road_map.map.tiles[TileKey(100, 0)].version == 9
    server.road_map.close()
