"""The fusion server's road-surface map: every solution it makes is map evidence, and the map is
shared with the agents on the bus (docs/roadmap.md, "Tiles on the bus").

One writer per map file (the fusion server of a run, or `coplane map build`). Solutions go through
the builder as they are made; closed passes are applied and committed in one transaction every
`commit_every_s` and when the server stops, so a `kill -9` loses at most the passes since the last
commit and never corrupts the file. A map that cannot be opened (corrupt, another schema, a file
that is no map) is logged as an error naming the file and the server runs without one; a failure
while learning is logged and counted; neither stops the server.

With regions (docs/scale.md, "The road map across servers") each server keeps its own file, a
whole replica: it adds evidence only to the tiles of the regions it owns (`owns_tile`; passes in
another server's tiles are counted `foreign-tile` and dropped), publishes them, and takes the other
servers' tiles from the bus (`take_peer`, newer versions from the tile's writer win) into its map
and file. Its file starts as a copy of the fleet's map file when it has none (`server_map`).

Agents do not take the whole map: each asks for the tiles around it and then for what changed
(`answer`, `coplane.steps.map_area`). Every tile is stamped with the revision at which it last
changed here (`RevisionIndex`), so an answer holds only what its asker lacks.
"""

from __future__ import annotations

import logging
import os
import sqlite3
import time
import uuid
from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from coplane.bus import BadMessage, BusNode, Request, decode, encode
from coplane.messages import MAX_MAP_COUNTS, MapTilesMessage, MapTileState, NodeMessage, SolutionMessage
from coplane.roadmap import MapBuilder, RoadMap, TileKey, TilePlane
from coplane.roadmap.area import RevisionIndex
from coplane.roadmap.tile import PassEvidence
from coplane.steps.map_area import AreaQuery, answer_tiles
from coplane.steps.map_evidence import solution_samples
from coplane.steps.map_tiles import CHUNK_TILES, merge_tile_states, tiles_messages
from coplane.store import server_map_path
from coplane.store.roadmap_db import RoadMapDb

from .map_queries import SLICE_S, QueryQueue
from .regions import RegionRole
from .settings import FusionSettings
from .tile_json import EncodedTiles

log = logging.getLogger("coplane.fusion_server.road_map")


class LiveRoadMap:
    """The map file this server extends, with its builder and counters."""

    def __init__(
        self,
        path: Path,
        antenna_heights: Mapping[str, float],
        commit_every_s: float = 10.0,
        fleet: str = "",
        snapshot_every_s: float = 60.0,
        server: str = "",
        owns_tile: Callable[[TileKey, float], bool] | None = None,
        tile_writers: Callable[[TileKey, float], set[str] | None] | None = None,
    ) -> None:
        self.db = RoadMapDb(path)
        self.map: RoadMap = self.db.load()
        self.builder = MapBuilder(self.map.config)
        self.heights = dict(antenna_heights)
        self.commit_every_s = commit_every_s
        self.last_commit = time.monotonic()
        self.counts: Counter[str] = Counter()
        # for the bus: the whole map now and every `snapshot_every_s`, each commit's tiles between
        self.fleet = fleet
        self.server, self.owns_tile = server, owns_tile  # regions: this server's id and tiles
        self.tile_writers = tile_writers  # ... and whose copy of a tile to take (None: anyone's)
        # regions: when the live servers last changed, i.e. who writes which tile (`answer`)
        self.writers_since: Callable[[], float] | None = None
        self.snapshot_every_s = snapshot_every_s
        self.snapshot = 0
        self.last_snapshot = time.monotonic()
        self.outbox: list[MapTilesMessage] = self._snapshot()
        # agents' area queries: this process's run and each tile's revision (`answer`)
        self.run = uuid.uuid4().hex[:12]
        self.index = RevisionIndex()
        self.index.touch(self.map.tiles)
        self.encoded = EncodedTiles()
        self.queries = QueryQueue(self.counts)  # answered between solves (`serve_queries`)
        log.info("road map open", extra={"path": str(path), **self.map.stats()})

    @classmethod
    def open(
        cls,
        path: Path,
        antenna_heights: Mapping[str, float],
        commit_every_s: float = 10.0,
        fleet: str = "",
        snapshot_every_s: float = 60.0,
        server: str = "",
        owns_tile: Callable[[TileKey, float], bool] | None = None,
        tile_writers: Callable[[TileKey, float], set[str] | None] | None = None,
    ) -> LiveRoadMap | None:
        """The map at `path` (created if missing), or None with the reason logged."""
        try:
            return cls(
                path,
                antenna_heights,
                commit_every_s,
                fleet,
                snapshot_every_s,
                server,
                owns_tile,
                tile_writers,
            )
        except Exception as exc:
            log.error("road map not used: %s", exc, extra={"path": str(path)})
            return None

    @classmethod
    def for_server(
        cls,
        path: Path,
        s: FusionSettings,
        heights: Mapping[str, float],
        fleet: str,
        regions: RegionRole | None,
    ) -> LiveRoadMap | None:
        """The map a server with these settings extends: the fleet's file, or with regions its own
        replica and tiles (docs/scale.md); None with the reason logged."""
        live = cls.open(
            path if regions is None else server_map(path, s.server_id),
            heights,
            s.map_commit_every_s,
            fleet,
            s.map_snapshot_every_s,
            *(() if regions is None else (s.server_id, regions.owns_tile, regions.tile_writers)),
        )
        if live is not None and regions is not None:
            live.writers_since = lambda: regions.servers_changed_at
        return live

    def add(self, sol: SolutionMessage, msgs: Mapping[str, NodeMessage]) -> None:
        """One solution's vehicle-epochs into the builder (never raises)."""
        try:
            for s in solution_samples(sol, msgs, self.heights):
                if self.map.is_mapped(s.vehicle_id, s.time_s):
                    self.counts["already-mapped"] += 1  # a replay of what the map holds
                    continue
                self.builder.add(s)
                self.counts["samples"] += 1
        except Exception:
            self.counts["errors"] += 1
            log.exception("road map: solution not added", extra={"seq": sol.seq})

    def diagnostics(self) -> dict[str, Any]:
        """The map fields of the server's diagnostics message: what became of the fleet's evidence
        (`map_counts`: samples taken, passes added, samples the trust filter skipped by reason, ...;
        a map that learns nothing, e.g. from a standalone fleet, shows why) and the map's common
        residual with the passes behind it (`map_common_offset_m`), each only once there is one."""
        out: dict[str, Any] = {}
        if counts := self.evidence_counts():
            out["map_counts"] = dict(sorted(counts.items())[:MAX_MAP_COUNTS])
        if (ref := self.map.common.latest) is not None:
            out.update(map_common_offset_m=ref.offset_m, map_common_passes=ref.passes)
        return out

    def evidence_counts(self) -> Counter[str]:
        """This server's counts and its builder's skipped samples (`skipped:<reason>`)."""
        return self.counts + Counter({f"skipped:{k}": n for k, n in self.builder.skipped.items()})

    @property
    def cache_size(self) -> int:
        """Messages the bus publisher keeps for late joiners: two whole snapshots and room for the
        commits between them."""
        return max(256, 4 * (len(self.map.tiles) // CHUNK_TILES + 1))

    def tick(self, now: float | None = None) -> None:
        """Commit the passes closed so far, at most every `commit_every_s`; a new whole snapshot
        for the bus every `snapshot_every_s`."""
        now = time.monotonic() if now is None else now
        if now - self.last_commit >= self.commit_every_s:
            self._commit(self.builder.passes_ready())
            self.last_commit = now
        if now - self.last_snapshot >= self.snapshot_every_s:
            self.outbox += self._snapshot()
            self.last_snapshot = now

    def take_outbox(self) -> list[MapTilesMessage]:
        """The tile messages to publish, oldest first (the server puts them on the bus)."""
        out, self.outbox = self.outbox, []
        return out

    def publish(self, node: BusNode, key: str) -> None:
        """Put the pending tile messages on `key` (never raises: the map is a side product)."""
        for msg in self.take_outbox():
            try:
                node.put(key, encode(msg))
            except Exception:
                self.counts["publish-errors"] += 1
                log.exception("road map tiles not published", extra={"snapshot": msg.snapshot})

    def enqueue(self, request: Request, key: str) -> None:
        """An agent's area query, to be answered on `key` between solves (`serve_queries`)."""
        self.queries.add(request, key, self._refuse)

    def serve_queries(self, slice_s: float = SLICE_S) -> int:
        """Answer the waiting area queries for about `slice_s`; how many were answered."""
        return self.queries.serve(self.answer, self._refuse, slice_s) if self.queries else 0

    def answer(self, request: Request, key: str) -> None:
        """An agent's area query: the tiles around it that it lacks, as one answer on `key` (this
        server's tiles key). A query that does not parse gets an error reply naming what is
        wrong and is counted (`query-rejected`); nothing here raises into the server."""
        try:
            query = AreaQuery.parse(request.parameters)
        except ValueError as exc:
            self.counts["query-rejected"] += 1
            self._finish(request, key, (), f"bad area query: {exc}")
            return
        try:
            run = self.answer_run()
            tiles = self._written_here(answer_tiles(self.map, self.index, query, self.server, run))
            payloads = self.encoded.answer(
                self.fleet, tiles, self.map.config, self.server, run, self.index.revision
            )
        except Exception as exc:
            self.counts["errors"] += 1
            log.exception("road map: area query not answered")
            self._finish(request, key, (), f"area query not answered: {type(exc).__name__}")
            return
        self.counts["queries"] += 1
        self.counts["query-tiles"] += len(tiles)
        self._finish(request, key, payloads)

    def answer_run(self) -> str:
        """The run an answer names: this process's, and with regions also when the live servers
        last changed. Who writes which tile changes only then, and a server that now writes more
        tiles must answer an agent's box whole, not only what changed since its last answer."""
        if self.writers_since is None:
            return self.run
        return f"{self.run}{int(self.writers_since() * 1000) & 0xFFFFFFF:07x}"

    def _written_here(self, tiles: list[TilePlane]) -> list[TilePlane]:
        """Regions: the tiles this server writes, and those whose writer is not known now (the
        grace time after a change); every server holds a replica, but only a tile's writer
        answers for it, so an agent gets one copy of each tile, not one per server."""
        if self.tile_writers is None:
            return tiles
        size = self.map.config.tile_size_m
        return [t for t in tiles if (w := self.tile_writers(t.key, size)) is None or self.server in w]

    def _refuse(self, request: Request, key: str, error: str) -> None:
        self._finish(request, key, (), error)

    def _finish(
        self, request: Request, key: str, payloads: Sequence[bytes], error: str | None = None
    ) -> None:
        try:
            BusNode.answer(request, key, payloads, error)
        except Exception:  # the asker gone, the session closing: its `Answered` comes by timeout
            self.counts["query-reply-errors"] += 1

    def take_peer(self, payload: bytes, sender: str | None = None) -> int:
        """Regions: another server's tiles from the bus into this map and its file; the number
        taken. Its own batches (which the subscription also hears) and other fleets' are skipped; a
        bad batch or tile is counted by reason and never raises. Only a tile's writer is believed
        about it (`tile_writers`): a server's snapshot also carries its replicas of the others'
        tiles (skipped, `peer-not-writer`), and no server overwrites the tiles another writes.
        `sender`: the server the batch's key names; a batch that says it is another server's is
        dropped (`peer-rejected:wrong-sender`), since only the key is tied to the writer's
        certificate (docs/scale.md)."""
        try:
            msg = decode(MapTilesMessage, payload)
        except BadMessage as exc:
            self.counts[f"peer-rejected:{exc.kind}"] += 1
            return 0
        if sender is not None and msg.server != sender:
            self.counts["peer-rejected:wrong-sender"] += 1
            return 0
        if msg.server == self.server or msg.fleet != self.fleet:
            return 0
        if msg.tile_size_m != self.map.config.tile_size_m:
            self.counts["peer-rejected:tile-size"] += 1
            return 0
        peer: Counter[str] = Counter()
        from_writer, unchecked = self._from_writer(msg, peer)
        taken = merge_tile_states(self.map, from_writer, peer, writer=True)
        taken += merge_tile_states(self.map, unchecked, peer)
        self.counts.update({f"peer-{k}": n for k, n in peer.items()})
        if taken:
            self.index.touch(t.key for t in taken)
            try:
                self.db.write(taken)  # the replica survives a restart of this server
            except Exception:
                self.counts["errors"] += 1
                log.exception("road map: peer tiles not stored", extra={"server": msg.server})
        return len(taken)

    def _from_writer(
        self, msg: MapTilesMessage, counts: Counter[str]
    ) -> tuple[list[MapTileState], list[MapTileState]]:
        """The tiles of `msg` its sender writes, and those whose writer is not known now (no
        regions, the grace time after a change); the rest is counted `not-writer`. A tile key
        that does not parse is left for `merge_tile_states` to reject by name."""
        if self.tile_writers is None:
            return [], list(msg.tiles)
        size = self.map.config.tile_size_m
        mine: list[MapTileState] = []
        unknown: list[MapTileState] = []
        for s in msg.tiles:
            try:
                writers = self.tile_writers(TileKey.parse(s.tile), size)
            except ValueError:
                writers = None
            if writers is None:
                unknown.append(s)
            elif msg.server in writers:
                mine.append(s)
            else:
                counts["not-writer"] += 1
        return mine, unknown

    def _snapshot(self) -> list[MapTilesMessage]:
        self.snapshot += 1
        tiles = [self.map.tiles[k] for k in sorted(self.map.tiles, key=lambda k: (k.row, k.col))]
        return tiles_messages(self.fleet, tiles, self.map.config, self.snapshot, True, self.server)

    def close(self) -> None:
        """Refuse the area queries still waiting; close every open pass, commit, checkpoint the
        file."""
        self.queries.close(self._refuse)
        try:
            self._commit(self.builder.flush())
        finally:
            log.info("road map closed", extra={**self.map.stats(), **dict(self.evidence_counts())})
            self.db.close()

    def _commit(self, passes: list[PassEvidence]) -> None:
        if self.owns_tile is not None:  # regions: one writer per tile, its region's owner
            size = self.map.config.tile_size_m
            mine = [p for p in passes if p.key is None or self.owns_tile(p.key, size)]
            self.counts["foreign-tile"] += len(passes) - len(mine)
            passes = mine
        if not passes:
            return
        try:
            changes = self.map.apply(passes)
            dirty = self.map.take_dirty()
            written = self.db.write(dirty, changes, mapped_until=self.map.mapped_until)
            self.index.touch(t.key for t in dirty)
            self.outbox += tiles_messages(
                self.fleet, dirty, self.map.config, self.snapshot, False, self.server
            )
        except Exception:
            self.counts["errors"] += 1
            log.exception("road map: batch not committed", extra={"passes": len(passes)})
            return
        self.counts["passes_added"] += len(passes)
        self.counts["changes_found"] += len(changes)
        for c in changes:
            log.warning(
                "road map: tile changed",
                extra={"tile": str(c.key), "old_height_m": c.old_height_m, "new_height_m": c.new_height_m},
            )
        log.debug("road map committed", extra={"passes": len(passes), "tiles": written})


def server_map(base: Path, server_id: str) -> Path:
    """Regions: this server's own map file beside the fleet's (`map-x.sqlite` -> `map-x.s1.sqlite`),
    first made as a copy of the fleet's file if that exists, so a map built beforehand (`coplane
    map build`) feeds every server. The copy is SQLite's online backup of a file opened read-only
    and checked as a map, written to a temporary name and renamed: a crash leaves no half copy. A
    base that cannot be read is logged and the server starts an empty map."""
    path = server_map_path(base, server_id)
    if path.exists() or not base.is_file():
        return path
    tmp = path.with_name(path.name + ".tmp")
    try:
        with RoadMapDb(base, readonly=True) as src:
            dst = sqlite3.connect(tmp)
            try:
                src.db.backup(dst)
            finally:
                dst.close()
        os.replace(tmp, path)
        log.info("road map copied for this server", extra={"from": str(base), "path": str(path)})
    except Exception as exc:
        tmp.unlink(missing_ok=True)
        log.error("road map not copied: %s", exc, extra={"from": str(base), "path": str(path)})
    return path
