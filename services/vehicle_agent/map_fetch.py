"""The agent's window on the fleet's road map: the tiles around the vehicle, asked of the fusion
servers as it moves, then what changed there every `refresh_s` (docs/roadmap.md, "Tiles on the
bus").

Why not take the servers' map stream: every agent would hold every tile of the fleet's map (a
city's map in every car) and hear every change anywhere. Here an agent asks for the box of tiles
within `radius_m` of its fix (`coplane.steps.map_area`), and asks again for a new box once it is
within half the radius of the box's edge, so a vehicle always has at least half the radius of map
ahead of it whichever way it turns, and asks without waiting for the answer (only its first
answer is awaited, by the agent). Each query names what the agent holds of each server's answers,
so a server sends only the tiles the agent lacks. Without a map file of its own the agent drops
the tiles outside its box (`evict`): its memory follows the box, not the fleet's map.
"""

from __future__ import annotations

import logging
import math
from collections import Counter

from numpy.typing import ArrayLike

from coplane.bus import Answered, BadMessage, BusNode, KeySpace, decode
from coplane.messages import MapTilesMessage
from coplane.roadmap import tile_of_ecef
from coplane.roadmap.area import TileBox
from coplane.runtime import RateLimitedLog
from coplane.steps.map_area import AreaQuery, Holding
from coplane.steps.map_tiles import MapReceiver

RETRY_S = 1.0  # a request nobody answered is asked again this soon


class MapFetch:
    """Which tiles to ask for, when, and what is held of each server's answers."""

    def __init__(
        self,
        keys: KeySpace,
        receiver: MapReceiver,
        radius_m: float = 1500.0,
        refresh_s: float = 10.0,
        timeout_s: float = 5.0,
        evict: bool = True,
    ) -> None:
        self.keys = keys
        self.receiver = receiver
        self.size_m = receiver.map.config.tile_size_m
        self.radius = max(2, math.ceil(radius_m / self.size_m))  # in tiles
        self.margin = self.radius // 2
        self.refresh_s, self.timeout_s, self.evict = refresh_s, timeout_s, evict
        self.box: TileBox | None = None  # the box asked for last
        self.held: dict[str, Holding] = {}  # per server: its last whole answer's run and revision
        self.pending: TileBox | None = None  # the box of the request in flight
        self.tag = 0
        self.sent_at = self.answered_at = -math.inf
        self.counts: Counter[str] = Counter()

    def follow(self, node: BusNode, position_ecef: ArrayLike, now: float) -> bool:
        """Ask for the tiles the vehicle at `position_ecef` needs, if a request is due (a new box,
        or `refresh_s` since the last answer) and none is in flight; whether one was sent."""
        if self.pending is not None:
            if now - self.sent_at < 2.0 * self.timeout_s:
                return False
            self.pending = None  # its end never came (the session in trouble): ask again
            self.counts["lost"] += 1
        try:
            key = tile_of_ecef(position_ecef, self.size_m)
        except ValueError:  # outside the grid (|lat| > 85 deg): no map there
            self.counts["off-grid"] += 1
            return False
        if self.box is None or not self.box.keeps(key, self.margin):
            self._move(TileBox.around(key, self.radius))
        elif now - self.answered_at < self.refresh_s:
            return False
        assert self.box is not None
        self.receiver.take_answers()  # a lost request's answers hold no box: not this one's
        self.tag += 1
        query = AreaQuery(self.box, tuple(self.held.values()))
        try:
            node.request(f"{self.keys.all_map_tiles}?{query.parameters()}", self.tag, self.timeout_s)
        except Exception:  # the session closing or lost: the map is a side product, ask later
            self.counts["request-errors"] += 1
            self.answered_at = now
            return False
        self.pending, self.sent_at = self.box, now
        self.counts["requests"] += 1
        return True

    def take(self, data: bytes, sender: str, warn: RateLimitedLog) -> None:
        """One message of a server's answer, from the tiles key of `sender`: taken by the
        receiver (which keeps bad tiles out); a payload that is no tiles message is counted
        (`bad-payload`) and logged, rate-limited. Never raises."""
        try:
            msg = decode(MapTilesMessage, data)
        except BadMessage as exc:
            self.counts["bad-payload"] += 1
            warn.log(logging.WARNING, ("tiles", exc.kind), "rejected map tiles", {"reason": str(exc)})
            return
        self.receiver.take(msg, sender)
        rejected = {k: n for k, n in self.receiver.counts.items() if k.startswith("rejected")}
        if rejected:
            warn.log(logging.WARNING, ("tiles", "rejected"), "map tiles rejected", rejected)

    def status(self) -> dict[str, int]:
        """The tiles held now and what the requests did (`map_<count>`: requests, answers, tiles
        dropped behind the vehicle, bad payloads) and the receiver's counts (`map_rejected:...`)."""
        counts = self.counts + Counter({k: n for k, n in self.receiver.counts.items() if k != "taken"})
        return {
            "map_tiles": len(self.receiver.map.tiles),
            **{f"map_{k}": n for k, n in sorted(counts.items())},
        }

    def finish(self, event: Answered, now: float) -> None:
        """The request ended (every answer is in and taken): what each server answered whole is
        now held, inside the box asked for."""
        if event.tag != self.tag or self.pending is None:
            return
        answers = self.receiver.take_answers()
        for server, (run, revision) in answers.items():
            self.held[server] = Holding(server, run, revision, self.pending)
        self.counts["answered" if answers else "unanswered"] += 1
        # nobody answered (no server with a map up yet): ask again after RETRY_S, not refresh_s
        self.pending = None
        self.answered_at = now if answers else now - self.refresh_s + min(RETRY_S, self.refresh_s)

    def _move(self, box: TileBox) -> None:
        """A new box: the tiles outside it dropped (`evict`), and each holding cut to what is
        still held, so no server leaves out a tile the agent no longer has."""
        self.box = box
        if self.evict:
            road_map = self.receiver.map
            self.counts["evicted"] += road_map.drop([k for k in road_map.tiles if k not in box])
        held: dict[str, Holding] = {}
        for server, h in self.held.items():
            if (kept := h.box.intersection(box)) is not None:
                held[server] = Holding(server, h.run, h.revision, kept)
        self.held = held
