"""Where a vehicle publishes when the fleet runs with regions (docs/scale.md).

The node key names the shard and region of the vehicle's own SPP fix (with the region grid's
hysteresis), so the fusion server that owns that region hears it; within `margin_m` of other
regions the same message is also put on a copy key of each of them, so their servers see a
vehicle that can range with theirs. Before the first fix the vehicle uses the fleet's base station
position (the recording's), the best guess of where the fleet is. Each home key has its own
publisher with the agent's history cache; the previous one is kept (a server taking over late
still finds its cache), older ones are undeclared. Copies have plain publishers, declared while
the vehicle is near that region.

Only the owner of the region a vehicle sent an epoch's message from may answer it (docs/scale.md,
"Boundaries"), and the agent knows that region: `may_answer` holds a server's solution that
speaks for this vehicle to it, so a server answering outside its regions (compromised, or with a
stale view of the live servers) is not taken for this vehicle's own position, its plane centre
or the car's NMEA output.
"""

from __future__ import annotations

import logging
from collections.abc import Set

import numpy as np

from coplane.bus import BusNode, KeySpace, Publication
from coplane.gtime import GpsTime
from coplane.messages import NodeMessage, SolutionMessage
from coplane.regions import RegionConfig, owner, region_of_ecef, regions_near, shard_of
from coplane.steps import gps_time

log = logging.getLogger("coplane.vehicle_agent")

NODE_HISTORY = 120  # node messages each publisher's cache keeps (a restarted server replays them)
SENT_KEPT = 4 * NODE_HISTORY  # epochs whose home region is remembered: past any replay of a cache


class RegionKeys:
    """The node key of each message, and the publishers behind those keys."""

    def __init__(self, keys: KeySpace, vehicle_id: str, cfg: RegionConfig, fallback_ecef: object) -> None:
        self.keys = keys
        self.vehicle_id = vehicle_id
        self.cfg = cfg
        self.fallback = None if fallback_ecef is None else np.asarray(fallback_ecef, dtype=float)
        self.region: str | None = None
        self.declared: list[str] = []  # newest last; at most 2 kept
        self.copies: set[str] = set()  # copy keys with a publisher now
        self.changes = 0
        self.copies_put = 0
        self.sent: dict[GpsTime, str] = {}  # the home region of each epoch sent (the last SENT_KEPT)

    def keys_for(self, msg: NodeMessage, node: BusNode) -> list[str]:
        """The keys to put `msg` on (publishers declared): its region's first, then the copies
        for the regions within the margin; empty when no position is known."""
        pos = msg.spp.position_ecef_m if msg.spp.ok else None
        home = self.home_key(pos, node)
        if home is None or self.region is None:
            return []
        copies = set()
        if pos is not None:
            for r in regions_near(pos, self.region, self.cfg):
                copies.add(
                    self.keys.region_copy(shard_of(r, self.cfg.shards), r, self.vehicle_id, self.region)
                )
        for k in sorted(self.copies - copies):
            node.remove_publication(k)
        for k in sorted(copies - self.copies):
            node.add_publication(Publication(k, must_deliver=True))
        self.copies = copies
        self.copies_put += len(copies)
        self.sent[gps_time(msg.epoch)] = self.region
        while len(self.sent) > SENT_KEPT:
            del self.sent[next(iter(self.sent))]
        return [home, *sorted(copies)]

    def may_answer(self, sol: SolutionMessage, servers: Set[str], settled: bool) -> bool:
        """Whether `sol` may speak for this vehicle: it does not (it names neither this vehicle's
        answer nor its state), or its server owns the region this vehicle sent that epoch from
        among the live `servers`. Unless the live servers are `settled` (`GateSet.settled`: known,
        and unchanged for MOVE_GRACE_S), or for an epoch not sent from here, every server may (the
        views of who owns what may differ; nothing to hold it to)."""
        if sol.server is None or not (
            sol.answers(self.vehicle_id) or any(v.vehicle_id == self.vehicle_id for v in sol.vehicles)
        ):
            return True
        region = self.sent.get(gps_time(sol.epoch))
        if region is None or not servers or not settled:
            return True
        return owner(shard_of(region, self.cfg.shards), servers) == sol.server

    def home_key(self, pos: tuple[float, float, float] | None, node: BusNode) -> str | None:
        """The key of the vehicle's own region (its publisher declared), None if unknown."""
        if pos is not None:
            region = region_of_ecef(pos, self.cfg, current=self.region)
        elif self.region is not None:
            region = self.region
        elif self.fallback is not None:
            region = region_of_ecef(self.fallback, self.cfg)
        else:
            return None
        if region != self.region:
            if self.region is not None:
                self.changes += 1
                log.info(
                    "region changed", extra={"vehicle": self.vehicle_id, "from": self.region, "to": region}
                )
            self.region = region
        key = self.keys.region_node(shard_of(region, self.cfg.shards), region, self.vehicle_id)
        if not self.declared or self.declared[-1] != key:
            node.add_publication(Publication(key, must_deliver=True, history=NODE_HISTORY))
            if key in self.declared:
                self.declared.remove(key)
            self.declared.append(key)
            while len(self.declared) > 2:
                node.remove_publication(self.declared.pop(0))
        return key
