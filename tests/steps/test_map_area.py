"""Area queries for road-map tiles (roadmap/area.py, steps/map_area.py): boxes, revisions, the
query's text and what a server answers, and hostile queries refused by name."""

from __future__ import annotations

import numpy as np
import pytest

from coplane.bus import decode, encode
from coplane.messages import MapTilesMessage
from coplane.roadmap import RoadMap, RoadMapConfig, TileKey, TilePlane
from coplane.roadmap.area import BLOCK_TILES, RevisionIndex, TileBox
from coplane.steps.map_area import MAX_HOLDINGS, AreaQuery, Holding, answer_tiles
from coplane.steps.map_tiles import CHUNK_TILES, MapReceiver, tiles_messages

CFG = RoadMapConfig()


def _tile(row: int, col: int, version: int = 1) -> TilePlane:
    return TilePlane(
        key=TileKey(row, col), h0_m=41.5, info=np.diag([40.0, 300.0, 300.0]), eta=np.array([4.0, 0.0, 0.0]),
        n_passes=4, n_points=40, version=version, updated_s=1.4e9,
    )  # fmt: skip


def test_a_box_around_a_tile_and_its_margin() -> None:
    box = TileBox.around(TileKey(10, -5), 4)
    assert box == TileBox(6, 14, -9, -1) and TileBox.parse(str(box)) == box
    assert TileKey(6, -9) in box and TileKey(15, -5) not in box and "r6c-9" not in box
    assert box.keeps(TileKey(10, -5), 2) and box.keeps(TileKey(8, -3), 2)
    assert not box.keeps(TileKey(7, -5), 2)  # one tile short of the margin
    assert box.intersection(TileBox(12, 30, -3, 0)) == TileBox(12, 14, -3, -1)
    assert box.intersection(TileBox(15, 30, -3, 0)) is None
    for bad in ("1,2,3", "1,2,3,x", "5,1,0,0", "1,2,3,4,5", ""):
        with pytest.raises(ValueError, match="box of tiles"):
            TileBox.parse(bad)


def test_the_index_gives_what_an_asker_lacks() -> None:
    idx = RevisionIndex()
    far = TileKey(5 * BLOCK_TILES, 0)  # in another block: never scanned for a box near 0
    assert idx.touch([TileKey(0, 0), TileKey(0, 1), TileKey(3, 3), far]) == 1
    box = TileBox(0, 2, 0, 2)
    assert idx.changed(box) == [TileKey(0, 0), TileKey(0, 1)]
    assert idx.changed(box, since=1, held=box) == []  # nothing new
    idx.touch([TileKey(0, 1)])
    assert idx.changed(box, since=1, held=box) == [TileKey(0, 1)]
    # moved: what lies outside the box held comes whole, the rest only if changed
    assert idx.changed(TileBox(0, 4, 0, 4), since=2, held=box) == [TileKey(3, 3)]
    assert idx.changed(TileBox(0, 4, 0, 4), since=1, held=box) == [TileKey(0, 1), TileKey(3, 3)]


def test_the_index_answers_past_its_log_by_scanning() -> None:
    """An asker whose revision is older than the log of recent changes still gets every tile it
    lacks: the box's blocks are scanned instead."""
    box = TileBox(0, 2, 0, 2)
    short, full = RevisionIndex(log_tiles=2), RevisionIndex()
    for idx in (short, full):
        idx.touch([TileKey(0, 0), TileKey(0, 1), TileKey(1, 1)])
        idx.touch([TileKey(0, 0)])
        idx.touch([TileKey(1, 1)])
        idx.touch([TileKey(2, 2)])
    assert short._since(1) is None and full._since(1) == {TileKey(0, 0), TileKey(1, 1), TileKey(2, 2)}
    for since in range(5):
        assert short.changed(box, since, box) == full.changed(box, since, box)
    assert full.changed(box, 1, box) == [TileKey(0, 0), TileKey(1, 1), TileKey(2, 2)]


def test_a_query_round_trips_and_hostile_ones_are_refused_by_name() -> None:
    q = AreaQuery(
        TileBox(0, 9, -4, 5),
        (Holding("", "ab12", 7, TileBox(0, 9, -4, 5)), Holding("s2", "cd", 3, TileBox(1, 2, 3, 4))),
    )
    params = dict(p.split("=", 1) for p in q.parameters().split(";"))
    assert AreaQuery.parse(params) == q
    assert q.holding("", "ab12") is q.held[0] and q.holding("", "other-run") is None
    assert AreaQuery.parse({"box": "0,1,0,1"}).held == ()
    cases = {
        "without box": {},
        "box of tiles": {"box": "1,0,0,0"},
        "wider than": {"box": "0,30000,0,1"},
        "expected server,run": {"box": "0,1,0,1", "held": "s1,ab,3"},
        "bad server id": {"box": "0,1,0,1", "held": "s 1,ab,3,0,1,0,1"},
        "more than": {"box": "0,1,0,1", "held": "|".join(["s,ab,1,0,1,0,1"] * (MAX_HOLDINGS + 1))},
    }
    for why, params in cases.items():
        with pytest.raises(ValueError, match=why):
            AreaQuery.parse(params)


def _answer(road_map: RoadMap, idx: RevisionIndex, query: AreaQuery, run: str) -> list[MapTilesMessage]:
    """A server's answer as it goes on the bus (services/fusion_server/tile_json.py writes the
    same bytes)."""
    tiles = answer_tiles(road_map, idx, query, "", run)
    return tiles_messages("f1", tiles, road_map.config, 0, True, "", run, idx.revision)


def test_an_answer_holds_the_box_in_parts_and_then_only_the_changes() -> None:
    tiles = [_tile(r, c) for r in range(30) for c in range(20)] + [_tile(500, 500)]
    road_map = RoadMap(CFG, {t.key: t for t in tiles})
    idx = RevisionIndex()
    idx.touch(road_map.tiles)
    box = TileBox(0, 29, 0, 19)
    first = _answer(road_map, idx, AreaQuery(box), "ab12")
    assert [m.parts for m in first] == [2, 2] and sum(len(m.tiles) for m in first) == 600 > CHUNK_TILES
    assert all((m.run, m.revision) == ("ab12", 1) for m in first)
    rx = MapReceiver("f1")
    for m in reversed(first):
        rx.take(decode(MapTilesMessage, encode(m)), "")
    assert len(rx.map.tiles) == 600 and TileKey(500, 500) not in rx.map.tiles
    assert rx.take_answers() == {"": ("ab12", 1)} and rx.take_answers() == {}
    # one tile changes: the next answer to the holding is that tile alone
    road_map.tiles[TileKey(3, 3)] = _tile(3, 3, version=2)
    idx.touch([TileKey(3, 3)])
    held = Holding("", "ab12", 1, box)
    again = _answer(road_map, idx, AreaQuery(box, (held,)), "ab12")
    assert [[t.tile for t in m.tiles] for m in again] == [["r3c3"]] and again[0].revision == 2
    # nothing new: still one (empty) message, so the asker learns the revision
    held2 = Holding("", "ab12", 2, box)
    assert [len(m.tiles) for m in _answer(road_map, idx, AreaQuery(box, (held2,)), "ab12")] == [0]
    # a restarted server (another run) answers the whole box
    assert sum(len(m.tiles) for m in _answer(road_map, idx, AreaQuery(box, (held2,)), "ff")) == 600
