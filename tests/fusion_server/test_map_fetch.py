"""An agent's map by area (docs/roadmap.md, "Tiles on the bus"): a vehicle driving along a road
asks the fusion server's map (`LiveRoadMap.answer`) for the tiles around it (`MapFetch`), through
an in-process stand-in for `BusNode.request`: it always has the tile under it, holds no more than
its box, receives each tile once, then only what changed, and all again from a restarted server."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from coplane.bus import Answered, KeySpace, Payload, Request, decode, encode
from coplane.fusion_server.road_map import LiveRoadMap
from coplane.fusion_server.tile_json import EncodedTiles
from coplane.messages import MapTilesMessage
from coplane.roadmap import RoadMapConfig, TileKey, TilePlane, tile_frame
from coplane.steps.map_tiles import CHUNK_TILES, MapReceiver, tiles_messages
from coplane.store.roadmap_db import RoadMapDb
from coplane.vehicle_agent.map_fetch import MapFetch

CFG = RoadMapConfig()
ROW, COLS = 2000, 200  # a straight road of 200 tiles (4 km)


def _tile(col: int, version: int = 1) -> TilePlane:
    return TilePlane(
        key=TileKey(ROW, col), h0_m=41.5, info=np.diag([40.0, 300.0, 300.0]), eta=np.array([4.0, 0.0, 0.0]),
        n_passes=4, n_points=40, version=version, updated_s=1.4e9,
    )  # fmt: skip


class _Query:
    def __init__(self) -> None:
        self.replies: list[tuple[str, bytes]] = []
        self.errors: list[bytes] = []

    def reply(self, key: str, data: bytes) -> None:
        self.replies.append((key, data))

    def reply_err(self, data: bytes) -> None:
        self.errors.append(data)

    def drop(self) -> None:
        pass


class _Bus:
    """`BusNode.request` answered at once by one server; the events as the agent would see them."""

    def __init__(self, server: LiveRoadMap, key: str) -> None:
        self.server, self.key = server, key
        self.events: list[Payload | Answered] = []

    def request(self, selector: str, tag: int = 0, timeout_s: float = 5.0) -> None:
        key, params = selector.split("?", 1)
        query = _Query()
        self.server.answer(Request(key, dict(p.split("=", 1) for p in params.split(";")), query), self.key)
        assert not query.errors, query.errors
        self.events += [Payload(k, d) for k, d in query.replies] + [Answered(key, tag)]


def _deliver(bus: _Bus, rx: MapReceiver, fetch: MapFetch, now: float) -> None:
    for ev in bus.events:
        if isinstance(ev, Payload):
            rx.take(decode(MapTilesMessage, ev.data), KeySpace.server_of_tiles_key(ev.key))
        else:
            fetch.finish(ev, now)
    bus.events.clear()


def test_a_vehicle_gets_the_map_around_it_as_it_drives(tmp_path: Path) -> None:
    path = tmp_path / "map.sqlite"
    with RoadMapDb(path) as db:
        db.write([_tile(c) for c in range(COLS)])
    server = LiveRoadMap(path, {}, fleet="f1")
    keys = KeySpace("f1")
    bus = _Bus(server, keys.map_tiles)
    rx = MapReceiver("f1")
    fetch = MapFetch(keys, rx, radius_m=200.0, refresh_s=10.0)  # 10 tiles each way
    box_tiles = 2 * fetch.radius + 1
    now = 0.0
    for col in range(COLS):  # one tile a second, 20 m/s
        now += 1.0
        position = tile_frame(TileKey(ROW, col), CFG.tile_size_m)[0]
        fetch.follow(bus, position, now)  # type: ignore[arg-type]
        _deliver(bus, rx, fetch, now)
        assert TileKey(ROW, col) in rx.map.tiles  # the plane under the vehicle is there
        assert len(rx.map.tiles) <= box_tiles  # and no more than its box
    # every tile came once: a new box sends only what the agent lacks, a refresh only changes
    assert server.counts["query-tiles"] == COLS
    assert fetch.counts["requests"] == server.counts["queries"] > 20 and fetch.counts["evicted"] > 0
    # a tile of the box changes on the server: the next refresh brings it alone
    near = TileKey(ROW, COLS - 3)
    server.map.tiles[near] = _tile(near.col, version=7)
    server.index.touch([near])
    assert not fetch.follow(bus, position, now + 1.0)  # type: ignore[arg-type]  # not due yet
    assert fetch.follow(bus, position, now + 10.0)  # type: ignore[arg-type]
    _deliver(bus, rx, fetch, now + 10.0)
    assert server.counts["query-tiles"] == COLS + 1 and rx.map.tiles[near].version == 7
    # a restarted server (a new run) does not know what the agent holds: it answers the box whole
    bus.server = restarted = LiveRoadMap(path, {}, fleet="f1")
    assert fetch.follow(bus, position, now + 20.0)  # type: ignore[arg-type]
    _deliver(bus, rx, fetch, now + 20.0)
    assert fetch.box is not None
    assert restarted.counts["query-tiles"] == sum(k in fetch.box for k in restarted.map.tiles) > 1
    server.close()
    restarted.close()


def test_a_bad_query_is_answered_with_an_error_and_counted(tmp_path: Path) -> None:
    server = LiveRoadMap(tmp_path / "map.sqlite", {}, fleet="f1")
    query = _Query()
    server.answer(Request("k", {"box": "9,1,0,0"}, query), "k")
    assert query.replies == [] and b"box of tiles" in query.errors[0]
    assert server.counts["query-rejected"] == 1 and "queries" not in server.counts
    server.close()


class _Nobody:
    """A bus where no server with a map is up yet: every request ends unanswered."""

    def request(self, selector: str, tag: int = 0, timeout_s: float = 5.0) -> None:
        pass


def test_an_unanswered_request_is_asked_again_within_a_second() -> None:
    """No server answered (none with a map up yet): the agent asks again after RETRY_S, not only
    at the next refresh, so a server that starts after the agents still feeds their first epochs."""
    fetch = MapFetch(KeySpace("f1"), MapReceiver("f1"), radius_m=200.0, refresh_s=10.0)
    position = tile_frame(TileKey(ROW, 5), CFG.tile_size_m)[0]
    assert fetch.follow(_Nobody(), position, 0.0)  # type: ignore[arg-type]
    fetch.finish(Answered("k", fetch.tag), 0.1)
    assert fetch.counts["unanswered"] == 1 and not fetch.held and fetch.pending is None
    assert not fetch.follow(_Nobody(), position, 0.5)  # type: ignore[arg-type]
    assert fetch.follow(_Nobody(), position, 1.2)  # type: ignore[arg-type]


def test_the_kept_json_is_the_models_bytes_and_follows_each_tile() -> None:
    """`EncodedTiles.answer` writes what `encode(tiles_messages(...))` writes, byte for byte, in
    parts; a tile's JSON is made again when its version changes or another copy replaces it."""
    tiles = [_tile(c) for c in range(CHUNK_TILES + 7)]
    enc = EncodedTiles()
    for some in (tiles, tiles[:3], []):
        want = [encode(m) for m in tiles_messages("f1", some, CFG, 0, True, "s1", "ab12", 9)]
        assert enc.answer("f1", some, CFG, "s1", "ab12", 9) == want
    t = tiles[0]
    before = enc.json(t)
    t.version += 1
    assert enc.json(t) != before and b'"version":2' in enc.json(t)
    copy = _tile(0, version=2)
    copy.h0_m = 50.0  # another server's copy at the same version, other evidence
    assert b'"h0_m":50.0' in enc.json(copy)


def test_with_regions_a_server_answers_the_tiles_it_writes(tmp_path: Path) -> None:
    """Regions: every server holds a replica, but answers only for the tiles it writes, so an
    agent gets one copy of each. When the live servers change (who writes what changes), the
    answers name a new run, so the server that now writes more answers the box whole."""
    path = tmp_path / "map.sqlite"
    with RoadMapDb(path) as db:
        db.write([_tile(c) for c in range(COLS)])
    writes_all = [False]  # s2 is live and writes the odd columns; then it is gone

    def writers(key: TileKey, _size: float) -> set[str] | None:
        return {"s1"} if writes_all[0] or key.col % 2 == 0 else {"s2"}

    changed_at = [100.0]
    s1 = LiveRoadMap(path, {}, fleet="f1", server="s1", tile_writers=writers)
    s1.writers_since = lambda: changed_at[0]
    keys = KeySpace("f1")
    bus = _Bus(s1, keys.server_tiles("s1"))
    rx = MapReceiver("f1")
    fetch = MapFetch(keys, rx, radius_m=200.0, refresh_s=10.0)
    position = tile_frame(TileKey(ROW, 100), CFG.tile_size_m)[0]
    assert fetch.follow(bus, position, 0.0)  # type: ignore[arg-type]
    _deliver(bus, rx, fetch, 0.0)
    box = fetch.box
    assert box is not None
    in_box = [k for k in s1.map.tiles if k in box]
    assert s1.counts["query-tiles"] == sum(k.col % 2 == 0 for k in in_box) > 0
    writes_all[0], changed_at[0] = True, 200.0  # s2 went: s1 writes every tile now
    assert fetch.follow(bus, position, 10.0)  # type: ignore[arg-type]
    _deliver(bus, rx, fetch, 10.0)
    assert s1.counts["query-tiles"] == sum(k.col % 2 == 0 for k in in_box) + len(in_box)
    assert fetch.held["s1"].run != s1.run and len(rx.map.tiles) == len(in_box)
    s1.close()


def test_a_lost_requests_late_answer_is_not_taken_for_the_next_box() -> None:
    """A request whose end never came is asked again after twice the timeout; an answer of the
    lost one that completes meanwhile covers no known box, so it is not held as the new one's."""
    rx = MapReceiver("f1")
    fetch = MapFetch(KeySpace("f1"), rx, radius_m=200.0, refresh_s=10.0, timeout_s=5.0)
    position = tile_frame(TileKey(ROW, 5), CFG.tile_size_m)[0]
    assert fetch.follow(_Nobody(), position, 0.0)  # type: ignore[arg-type]
    late = tiles_messages("f1", [_tile(5)], CFG, 0, True, "", "ab12", 5)
    rx.take(late[0], "")  # the lost request's answer, after all
    assert fetch.follow(_Nobody(), position, 11.0)  # type: ignore[arg-type]
    assert fetch.counts["lost"] == 1
    fetch.finish(Answered("k", fetch.tag), 11.5)  # the new request: nobody answered it
    assert fetch.held == {} and fetch.counts["unanswered"] == 1
