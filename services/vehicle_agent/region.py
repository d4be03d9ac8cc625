"""Where a vehicle publishes when the fleet runs with regions (docs/scale.md).

The node key names the shard and region of the vehicle's own SPP fix (with the region grid's
hysteresis), so the fusion server that owns that region hears it; within `margin_m` of other
regions the same message is also put on a copy key of each of them, so their servers see a
vehicle that can range with theirs. Before the first fix the vehicle uses the fleet's base station
position (the recording's), the best guess of where the fleet is. Each home key has its own
publisher with the agent's history cache; the previous one is kept (a server taking over late
still finds its cache), older ones are undeclared. Copies have plain publishers, declared while
the vehicle is near that region.
"""

from __future__ import annotations

import logging

import numpy as np

from coplane.bus import BusNode, KeySpace, Publication
from coplane.messages import NodeMessage
from coplane.regions import RegionConfig, region_of_ecef, regions_near, shard_of

log = logging.getLogger("coplane.vehicle_agent")

NODE_HISTORY = 120  # node messages each publisher's cache keeps (a restarted server replays them)


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
        return [home, *sorted(copies)]

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
