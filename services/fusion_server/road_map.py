"""The fusion server's road-surface map: every solution it makes is map evidence, and the map is
shared with the agents on the bus (docs/roadmap.md, "Tiles on the bus").

One writer per map file (the fusion server of a run, or `coplane map build`). Solutions go through
the builder as they are made; closed passes are applied and committed in one transaction every
`commit_every_s` and when the server stops, so a `kill -9` loses at most the passes since the last
commit and never corrupts the file. A map that cannot be opened (corrupt, another schema, a file
that is no map) is logged as an error naming the file and the server runs without one; a failure
while learning is logged and counted; neither stops the server.
"""

from __future__ import annotations

import logging
import time
from collections import Counter
from collections.abc import Mapping
from pathlib import Path

from coplane.messages import MapTilesMessage, NodeMessage, SolutionMessage
from coplane.roadmap import MapBuilder, RoadMap
from coplane.roadmap.tile import PassEvidence
from coplane.steps.map_evidence import solution_samples
from coplane.steps.map_tiles import CHUNK_TILES, tiles_messages
from coplane.store.roadmap_db import RoadMapDb

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
        self.snapshot_every_s = snapshot_every_s
        self.snapshot = 0
        self.last_snapshot = time.monotonic()
        self.outbox: list[MapTilesMessage] = self._snapshot()
        log.info("road map open", extra={"path": str(path), **self.map.stats()})

    @classmethod
    def open(
        cls,
        path: Path,
        antenna_heights: Mapping[str, float],
        commit_every_s: float = 10.0,
        fleet: str = "",
        snapshot_every_s: float = 60.0,
    ) -> LiveRoadMap | None:
        """The map at `path` (created if missing), or None with the reason logged."""
        try:
            return cls(path, antenna_heights, commit_every_s, fleet, snapshot_every_s)
        except Exception as exc:
            log.error("road map not used: %s", exc, extra={"path": str(path)})
            return None

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

    def _snapshot(self) -> list[MapTilesMessage]:
        self.snapshot += 1
        tiles = [self.map.tiles[k] for k in sorted(self.map.tiles, key=lambda k: (k.row, k.col))]
        return tiles_messages(self.fleet, tiles, self.map.config, self.snapshot, whole=True)

    def close(self) -> None:
        """Close every open pass, commit, checkpoint the file."""
        try:
            self._commit(self.builder.flush())
        finally:
            self.counts.update({f"skipped:{k}": n for k, n in self.builder.skipped.items()})
            log.info("road map closed", extra={**self.map.stats(), **dict(self.counts)})
            self.db.close()

    def _commit(self, passes: list[PassEvidence]) -> None:
        if not passes:
            return
        try:
            changes = self.map.apply(passes)
            dirty = self.map.take_dirty()
            written = self.db.write(dirty, changes, mapped_until=self.map.mapped_until)
            self.outbox += tiles_messages(self.fleet, dirty, self.map.config, self.snapshot, whole=False)
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
