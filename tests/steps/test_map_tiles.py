"""Road-map tiles on the bus (steps/map_tiles.py): round trip, snapshots, and bad tiles kept out."""

from __future__ import annotations

import numpy as np
import pytest

from coplane.bus import BadMessage, decode, encode
from coplane.messages import MapTilesMessage
from coplane.roadmap import RoadMap, RoadMapConfig, TileKey, TilePlane
from coplane.steps.map_tiles import CHUNK_TILES, MapReceiver, tile_of_state, tiles_messages

CFG = RoadMapConfig()


def _tile(row: int, col: int, version: int = 1) -> TilePlane:
    info = np.array([[4.0, 1.0, 0.5], [1.0, 30.0, 2.0], [0.5, 2.0, 25.0]])
    return TilePlane(
        key=TileKey(row, col), h0_m=41.5, info=info, eta=np.array([0.4, 0.1, -0.2]),
        n_passes=5, n_points=9, version=version, updated_s=1.4e9,
    )  # fmt: skip


def test_round_trip_keeps_what_plane_at_needs() -> None:
    t = _tile(3, -7)
    back = tile_of_state(
        decode(MapTilesMessage, encode(tiles_messages("f1", [t], CFG, 1, True)[0])).tiles[0], CFG
    )
    assert back.key == t.key and back.version == t.version and back.n_passes == t.n_passes
    np.testing.assert_array_equal(back.info, t.info)
    np.testing.assert_array_equal(back.eta, t.eta)
    assert back.height_at(2.0, -3.0, CFG) == t.height_at(2.0, -3.0, CFG)


def test_a_whole_map_arrives_in_parts_and_completes() -> None:
    tiles = [_tile(r, 0) for r in range(CHUNK_TILES + 10)]
    msgs = tiles_messages("f1", tiles, CFG, 4, True)
    assert [m.parts for m in msgs] == [2, 2] and [len(m.tiles) for m in msgs] == [CHUNK_TILES, 10]
    rx = MapReceiver("f1")
    rx.take(msgs[1])
    assert not rx.complete
    rx.take(msgs[0])
    assert rx.complete and len(rx.map.tiles) == len(tiles)
    # an empty map is one message: a receiver knows it has everything
    empty = tiles_messages("f1", [], CFG, 1, True)
    assert len(empty) == 1 and MapReceiver("f1").take(empty[0]) == 0
    # a commit's tiles are not a snapshot
    assert [m.parts for m in tiles_messages("f1", tiles[:3], CFG, 4, False)] == [0]
    assert tiles_messages("f1", [], CFG, 4, False) == []


def test_bad_tiles_are_counted_and_the_rest_kept() -> None:
    good, bad = _tile(0, 0), _tile(0, 1)
    bad.info[1, 1] = -500.0  # not positive definite even with the slope prior (1/0.08^2 = 156)
    rx = MapReceiver("f1")
    assert rx.take(tiles_messages("f1", [good, bad], CFG, 1, True)[0]) == 1
    assert set(rx.map.tiles) == {good.key}
    assert rx.counts["rejected:information matrix not positive definite"] == 1
    # older versions never replace newer ones; another fleet or tile size is rejected whole
    rx.take(tiles_messages("f1", [_tile(0, 0, version=0)], CFG, 2, False)[0])
    assert rx.map.tiles[good.key].version == 1 and rx.counts["older"] == 1
    assert rx.take(tiles_messages("f2", [_tile(5, 5)], CFG, 1, True)[0]) == 0
    other = RoadMapConfig(tile_size_m=50.0)
    assert rx.take(tiles_messages("f1", [_tile(6, 6)], other, 1, True)[0]) == 0
    assert rx.counts["rejected:wrong-fleet"] == 1 and rx.counts["rejected:tile-size"] == 1
    assert isinstance(rx.map, RoadMap)


def test_non_finite_or_malformed_tiles_do_not_decode() -> None:
    raw = encode(tiles_messages("f1", [_tile(0, 0)], CFG, 1, True)[0]).replace(b'"h0_m":41.5', b'"h0_m":NaN')
    with pytest.raises(BadMessage):
        decode(MapTilesMessage, raw)
    raw = encode(tiles_messages("f1", [_tile(0, 0)], CFG, 1, True)[0]).replace(
        b'"tile":"r0c0"', b'"tile":"x"'
    )
    with pytest.raises(BadMessage):
        decode(MapTilesMessage, raw)
