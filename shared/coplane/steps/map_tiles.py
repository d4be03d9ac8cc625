"""Road-map tiles on the bus: the fusion server's tiles as MapTilesMessage batches and back.

The fusion server (the map's one writer) publishes the whole map as one snapshot of `parts`
messages at start and then periodically, and the tiles of each commit between snapshots; its
publisher keeps a cache, so an agent that starts late still receives a whole snapshot
(docs/roadmap.md, "Tiles on the bus"). `MapReceiver` is the agents' side: every tile is checked
before it can reach a plane (finite numbers, a symmetric information matrix that is positive
definite with the slope prior, a sane height), a bad tile is counted by reason and the rest of the
batch is kept, and an older version never replaces a newer one.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable, Sequence

import numpy as np

from coplane.messages import MapTilesMessage, MapTileState
from coplane.roadmap import RoadMap, RoadMapConfig, TileKey, TilePlane

CHUNK_TILES = 500  # tiles per message: about 150 kB of JSON, well inside the bus's size bound
_UPPER = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))


def tile_state(t: TilePlane) -> MapTileState:
    """The shared part of a tile (its plane evidence and counters)."""
    return MapTileState(
        tile=str(t.key),
        h0_m=float(t.h0_m),
        info=[float(t.info[i, j]) for i, j in _UPPER],
        eta=[float(x) for x in t.eta],
        n_passes=t.n_passes,
        n_points=t.n_points,
        outlier_passes=t.outlier_passes,
        changes=t.changes,
        version=t.version,
        updated_s=float(t.updated_s),
    )


def tile_chunks(tiles: Sequence[TilePlane], whole: bool) -> list[Sequence[TilePlane]]:
    """`tiles` in parts of at most CHUNK_TILES, one message each; a whole map or answer is at
    least one (empty) part, a commit's changes none when there are no tiles."""
    chunks = [tiles[i : i + CHUNK_TILES] for i in range(0, len(tiles), CHUNK_TILES)]
    return chunks or ([[]] if whole else [])


def tiles_messages(
    fleet: str,
    tiles: Sequence[TilePlane],
    config: RoadMapConfig,
    snapshot: int,
    whole: bool,
    server: str = "",
    run: str = "",
    revision: int = 0,
) -> list[MapTilesMessage]:
    """`tiles` in messages of at most CHUNK_TILES; `whole`: they are the whole map or a whole
    answer (parts = count, at least one message even for no tiles), else a commit's changes
    (parts = 0). `server`: the writer's id with regions (docs/scale.md, "The road map across
    servers"); `run`, `revision`: an area answer's (`coplane.steps.map_area`)."""
    chunks = tile_chunks(tiles, whole)
    return [
        MapTilesMessage(
            fleet=fleet,
            server=server,
            tile_size_m=config.tile_size_m,
            snapshot=snapshot,
            part=i,
            parts=len(chunks) if whole else 0,
            tiles=[tile_state(t) for t in chunk],
            run=run,
            revision=revision,
        )
        for i, chunk in enumerate(chunks)
    ]


def tile_of_state(s: MapTileState, config: RoadMapConfig) -> TilePlane:
    """The tile a state describes; ValueError naming the tile and what is wrong with it."""
    key = TileKey.parse(s.tile)
    info = np.zeros((3, 3))
    for (i, j), v in zip(_UPPER, s.info, strict=True):
        info[i, j] = info[j, i] = v
    eta = np.array(s.eta, dtype=float)
    tile = TilePlane(
        key=key,
        h0_m=s.h0_m,
        info=info,
        eta=eta,
        n_passes=s.n_passes,
        n_points=s.n_points,
        outlier_passes=s.outlier_passes,
        changes=s.changes,
        version=s.version,
        updated_s=s.updated_s,
    )
    if (why := tile.problem(config)) is not None:
        raise ValueError(f"tile {key}: {why}")
    return tile


def merge_tile_states(
    road_map: RoadMap, states: Iterable[MapTileState], counts: Counter[str], writer: bool = False
) -> list[TilePlane]:
    """Newer tile versions from the bus into `road_map`; the tiles taken. A bad tile is counted
    by reason (`rejected:<why>`) and skipped, an older or equal version is counted and ignored: the
    agents' and, with regions, the other servers' way in (never raises for a bad tile).

    `writer`: the states come from the tiles' writer, whose copy also wins at an equal version
    when it differs (`conflict`): two servers that both wrote a tile across a region move reach
    the same version with different evidence, and the writer's is the one that goes on."""
    taken: list[TilePlane] = []
    for s in states:
        try:
            tile = tile_of_state(s, road_map.config)
        except ValueError as exc:
            reason = str(exc).split(": ", 1)[-1]
            counts[f"rejected:{reason}"] += 1
            continue
        old = road_map.tiles.get(tile.key)
        if old is not None and old.version >= tile.version:
            if not (writer and old.version == tile.version and _differs(old, tile)):
                counts["older"] += 1
                continue
            counts["conflict"] += 1
        road_map.tiles[tile.key] = tile
        counts["taken"] += 1
        taken.append(tile)
    return taken


def _differs(a: TilePlane, b: TilePlane) -> bool:
    """Whether two copies of a tile hold different evidence (what the bus carries of it)."""
    return (
        a.h0_m != b.h0_m
        or not np.array_equal(a.info, b.info)
        or not np.array_equal(a.eta, b.eta)
        or (a.n_passes, a.n_points) != (b.n_passes, b.n_points)
    )


class MapReceiver:
    """An agent's map from the bus: `take` each MapTilesMessage; `complete` once a whole snapshot
    (of any one server) has arrived. `counts` has tiles taken, older versions ignored and
    rejections by reason."""

    def __init__(
        self, fleet: str, road_map: RoadMap | None = None, config: RoadMapConfig | None = None
    ) -> None:
        self.fleet = fleet
        self.map = road_map if road_map is not None else RoadMap(config or RoadMapConfig())
        self.counts: Counter[str] = Counter()
        self._parts: dict[tuple[str, int], set[int]] = {}
        self.complete = False
        # area answers (`coplane.steps.map_area`): the parts seen of each, and per server the
        # (run, revision) of the last answer whose every part arrived, until `take_answers`
        self._answer_parts: dict[tuple[str, str, int], set[int]] = {}
        self._answers: dict[str, tuple[str, int]] = {}

    def take(self, msg: MapTilesMessage, sender: str | None = None) -> int:
        """Apply one batch; the number of tiles it changed. Never raises for bad tiles. `sender`:
        the server its key names (`KeySpace.server_of_tiles_key`, "" for the single server's
        key); a batch that says it is another server's is from the wrong sender and is dropped
        whole (`rejected:wrong-sender`): on a secure bus the key is what the router's ACL ties
        to the writer's certificate. None: not checked (in-process use)."""
        if sender is not None and msg.server != sender:
            self.counts["rejected:wrong-sender"] += 1
            return 0
        if msg.fleet != self.fleet:
            self.counts["rejected:wrong-fleet"] += 1
            return 0
        if msg.tile_size_m != self.map.config.tile_size_m:
            self.counts["rejected:tile-size"] += 1
            return 0
        changed = len(merge_tile_states(self.map, msg.tiles, self.counts))
        if msg.run and msg.parts > 0 and msg.part < msg.parts:
            seen = self._answer_parts.setdefault((msg.server, msg.run, msg.revision), set())
            seen.add(msg.part)
            if len(seen) == msg.parts:
                self._answers[msg.server] = (msg.run, msg.revision)
                del self._answer_parts[(msg.server, msg.run, msg.revision)]
                self.complete = True
        elif msg.parts > 0 and msg.part < msg.parts:
            # per server: with regions every server publishes snapshots numbered from 1
            seen = self._parts.setdefault((msg.server, msg.snapshot), set())
            seen.add(msg.part)
            if len(seen) == msg.parts:
                self.complete = True
                self._parts.clear()
        return changed

    def take_answers(self) -> dict[str, tuple[str, int]]:
        """Per server, the (run, revision) of the last area answer that arrived whole since the
        last call; parts of unfinished answers are forgotten (their tiles are kept)."""
        out, self._answers = self._answers, {}
        self._answer_parts.clear()
        return out
