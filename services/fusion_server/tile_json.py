"""The wire JSON of the road map's tiles, kept per tile version, for the agents' area answers.

Why not build each answer with the models, as `tiles_messages` and `encode` do: a whole box is
thousands of tiles, and building and encoding one tile's model costs about 10 us, so a first
answer held a fusion server's loop for 40-60 ms (bench/roadmap_fetch.py), while most tiles of an
answer have not changed since the last answer that carried them. Each message here is encoded
without its tiles and the tiles' kept JSON is put in its empty list: the same bytes as `encode`
of `tiles_messages(...)` (tests/fusion_server/test_map_fetch.py checks it). It keeps the JSON of every
tile ever answered (about 0.2 kB each, bench/roadmap_fetch.py), at most the map's tiles.
"""

from __future__ import annotations

from collections.abc import Sequence

from coplane.bus import encode
from coplane.messages import MapTilesMessage
from coplane.roadmap import RoadMapConfig, TileKey, TilePlane
from coplane.steps.map_tiles import tile_chunks, tile_state

_EMPTY = b'"tiles":[]'


class EncodedTiles:
    """Each tile's JSON, kept while the tile object and its version stay the same (a tile taken
    from another server is a new object, a pass adds a version)."""

    def __init__(self) -> None:
        self._json: dict[TileKey, tuple[TilePlane, int, bytes]] = {}

    def json(self, t: TilePlane) -> bytes:
        """`tile_state(t)` as `encode` writes it inside a message."""
        got = self._json.get(t.key)
        if got is None or got[0] is not t or got[1] != t.version:
            got = self._json[t.key] = (t, t.version, tile_state(t).model_dump_json(by_alias=True).encode())
        return got[2]

    def answer(
        self,
        fleet: str,
        tiles: Sequence[TilePlane],
        config: RoadMapConfig,
        server: str,
        run: str,
        revision: int,
    ) -> list[bytes]:
        """The encoded messages of one whole answer: `tiles` in parts (`tile_chunks`, one empty
        message for none), each with the server's `run` and `revision`."""
        chunks = tile_chunks(tiles, whole=True)
        out = []
        for i, chunk in enumerate(chunks):
            envelope = MapTilesMessage(
                fleet=fleet, server=server, tile_size_m=config.tile_size_m, snapshot=0, part=i,
                parts=len(chunks), tiles=[], run=run, revision=revision,
            )  # fmt: skip
            body = b'"tiles":[' + b",".join(self.json(t) for t in chunk) + b"]"
            out.append(encode(envelope).replace(_EMPTY, body, 1))
        return out
