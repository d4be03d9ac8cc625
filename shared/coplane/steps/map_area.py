"""Area queries for road-map tiles: an agent asks the fusion servers for the tiles around it, and
for what changed since its last answer (docs/roadmap.md, "Tiles on the bus").

The query's selector parameters are `box=<row0,row1,col0,col1>` (the tiles wanted) and
`held=<holding>|...`, one holding per server that answered before:
`<server>,<run>,<revision>,<row0>,<row1>,<col0>,<col1>` (what the agent holds of that server's
answers: up to which revision, inside which box). A server answers with the tiles of the box that
the holding for its own id and run lacks (`RevisionIndex.changed`); with no holding for its
current run (first query, a restarted server) it answers the whole box. Every answer, even an
empty one, carries the server's run and revision, so the agent's next holding is exact.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass

from coplane.roadmap import RoadMap, TilePlane
from coplane.roadmap.area import RevisionIndex, TileBox

MAX_HOLDINGS = 64  # servers named in one query: far more than a fleet's regions
MAX_BOX_SIDE = 20000  # tiles: 400 km at 20 m, a bound on what one query may name
_SERVER = re.compile(r"^[A-Za-z0-9_-]{0,32}$")
_RUN = re.compile(r"^[0-9a-f]{1,32}$")


@dataclass(frozen=True)
class Holding:
    """What an agent holds of one server's answers: that server's `run`, the `revision` its last
    whole answer was at, and the `box` the agent kept of it."""

    server: str
    run: str
    revision: int
    box: TileBox

    def __str__(self) -> str:
        return f"{self.server},{self.run},{self.revision},{self.box}"

    @classmethod
    def parse(cls, text: str) -> Holding:
        """The inverse of `str`; ValueError naming the text and what is wrong."""
        parts = text.split(",")
        if len(parts) != 7:
            raise ValueError(f"holding {text[:80]!r}: expected server,run,revision,row0,row1,col0,col1")
        server, run, rev = parts[:3]
        if not _SERVER.match(server) or not _RUN.match(run) or not rev.isdigit() or len(rev) > 15:
            raise ValueError(f"holding {text[:80]!r}: bad server id, run or revision")
        return cls(server, run, int(rev), TileBox.parse(",".join(parts[3:])))


@dataclass(frozen=True)
class AreaQuery:
    """The tiles an agent asks for (`box`) and what it holds already (`held`)."""

    box: TileBox
    held: tuple[Holding, ...] = ()

    def parameters(self) -> str:
        """The selector's parameters (after the `?`)."""
        text = f"box={self.box}"
        return f"{text};held={'|'.join(str(h) for h in self.held)}" if self.held else text

    @classmethod
    def parse(cls, parameters: Mapping[str, str]) -> AreaQuery:
        """A query from its selector parameters; ValueError naming what is wrong (the queries come
        from any agent of the fleet: nothing in them is trusted)."""
        if "box" not in parameters:
            raise ValueError("area query without box=row0,row1,col0,col1")
        box = TileBox.parse(parameters["box"])
        if box.row1 - box.row0 >= MAX_BOX_SIDE or box.col1 - box.col0 >= MAX_BOX_SIDE:
            raise ValueError(f"area query box {box} is wider than {MAX_BOX_SIDE} tiles")
        text = parameters.get("held", "")
        items = [h for h in text.split("|") if h] if text else []
        if len(items) > MAX_HOLDINGS:
            raise ValueError(f"area query names {len(items)} holdings, more than {MAX_HOLDINGS}")
        return cls(box, tuple(Holding.parse(h) for h in items))

    def holding(self, server: str, run: str) -> Holding | None:
        """The asker's holding of this server's current run, if any."""
        return next((h for h in self.held if h.server == server and h.run == run), None)


def answer_tiles(
    road_map: RoadMap, index: RevisionIndex, query: AreaQuery, server: str, run: str
) -> list[TilePlane]:
    """One server's answer to `query`: the tiles of the box its asker lacks, by key. The server
    sends them as one answer (`tiles_messages(..., whole=True)` with its run and the index's
    revision: at least one message, so an empty answer still gives the asker the revision)."""
    held = query.holding(server, run)
    keys = index.changed(query.box) if held is None else index.changed(query.box, held.revision, held.box)
    return [road_map.tiles[k] for k in keys if k in road_map.tiles]
