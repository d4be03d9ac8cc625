"""A fusion server's part in a fleet spread over several servers by region (docs/scale.md).

`RegionRole` keeps what one server needs to know and decide, with no coordinator:
- the live servers (their liveliness tokens `alive/fusion/<id>`) and so the shards this one owns
  (`coplane.regions.owned_shards`, rendezvous hashing: every server computes the same split);
- the node keys to subscribe to: its shards (`wanted`); vehicles near a boundary also send a copy
  to the regions across it, so a cluster across a boundary is seen by the servers on both sides;
- which clusters of an epoch it solves, those with a vehicle of its regions, and whom it answers
  for, the vehicles of its regions (`select`);
- the seeds for vehicles it takes over: their last state in another server's solution, so a
  vehicle that crosses into this server's region continues instead of starting afresh (`seeds`).
"""

from __future__ import annotations

import logging
import time
from collections import Counter
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from coplane.bus import BusNode, KeySpace, Subscription
from coplane.estimation.contract import VehicleSeed
from coplane.gtime import GpsTime
from coplane.messages import NodeMessage, SolutionMessage, VehicleState
from coplane.regions import (
    MOVE_GRACE_S,
    RangeGraph,
    RegionConfig,
    owned_shards,
    owner,
    region_of_tile,
    regions_near,
    shard_of,
)
from coplane.roadmap import TileKey
from coplane.steps import gps_time

log = logging.getLogger("coplane.fusion_server")

SETTLE_S = 1.0  # lockstep start: no new vehicle heard for this long, the fleet of this server is complete
PEER_STATE_MAX = 100_000
REGION_AT_MAX = 1_000_000  # pending (vehicle, epoch) regions kept (the admission bounds pending far lower)  # vehicles whose last state from another server is kept (bounded memory)


@dataclass(frozen=True)
class Selection:
    """One epoch's decision: the messages to solve, the vehicles to answer for (those of this
    server's regions), and the vehicles another server answers (solved here or not)."""

    solve: dict[str, NodeMessage]
    answer: set[str]
    others: list[str]


class RegionRole:
    """Ownership, subscriptions, cluster selection and hand-over seeds of one server."""

    def __init__(
        self,
        me: str,
        keys: KeySpace,
        cfg: RegionConfig,
        window_s: float,
        expected_servers: int,
    ) -> None:
        self.me = me
        self.keys = keys
        self.cfg = cfg
        self.expected_servers = max(1, expected_servers)
        self.servers: set[str] = {me}
        self.shards: set[int] = owned_shards(me, self.servers, cfg.shards)
        self.region: dict[str, str] = {}  # vehicle -> its own region at its latest epoch heard
        self.region_t: dict[str, GpsTime] = {}
        self.graph = RangeGraph(window_s)
        self.peer_state: dict[str, tuple[GpsTime, VehicleState]] = {}
        self.answered_elsewhere: dict[str, GpsTime] = {}  # latest epoch another server answered
        # vehicles whose next message will reach this server (see saw_node); the margin less one
        # epoch of driving at 30 m/s
        self.coming: set[str] = set()
        self.inner = RegionConfig(cfg.size_m, cfg.shards, cfg.hysteresis_m, max(0.0, cfg.margin_m - 30.0))
        self.version = 0  # bumped by every change `awaited` depends on (it is cached on it)
        self._awaited: tuple[tuple[object, ...], set[str]] | None = None
        self.solving: set[str] = set()  # vehicles of this server's last solved epoch
        self.counts: Counter[str] = Counter()
        self.ready = expected_servers <= 1  # subscribe to nodes only once the expected servers are seen
        self.dirty = True  # the wanted subscriptions may have changed since the last sync
        self.heard: set[str] = set()  # vehicles heard at least once
        # the region of each pending message: servers decide an epoch by where the vehicles were
        # then, not by a later message one of them may already have
        self.region_at: dict[tuple[str, GpsTime], str] = {}
        self.ready_at: float | None = None  # monotonic time the node subscriptions were made
        self.servers_changed_at = time.monotonic()  # the live servers last changed (start: now)
        self.last_new_speaker: float | None = None

    # -- membership ----------------------------------------------------------------------------
    def server_presence(self, ident: str, alive: bool) -> bool:
        """A server's token came or went; True if this server's shards changed."""
        if ident == self.me:
            return False
        before = len(self.servers)
        (self.servers.add if alive else self.servers.discard)(ident)
        if len(self.servers) != before:
            self.servers_changed_at = time.monotonic()
        if len(self.servers) >= self.expected_servers and not self.ready:
            self.ready = self.dirty = True
        new = owned_shards(self.me, self.servers, self.cfg.shards)
        if new == self.shards:
            return False
        log.info(
            "shards reassigned",
            extra={"servers": ",".join(sorted(self.servers)), "owned": len(new), "was": len(self.shards)},
        )
        self.shards = new
        self.dirty = True
        self.version += 1
        self.counts["reassignments"] += 1
        return True

    def settled(self, now: float, live: set[str]) -> bool:
        """Lockstep start: solve once every live agent was heard, or once no new one was heard
        for `SETTLE_S` after the subscriptions were made (the agents of other servers' regions
        never speak to this one; an agent's first message reaches a late subscription through
        its cache)."""
        if not self.ready or self.ready_at is None:
            return False
        if live <= self.heard:
            return True
        last = max(self.ready_at, self.last_new_speaker or self.ready_at)
        return now - last >= SETTLE_S

    def start_anyway(self) -> None:
        """The expected servers did not all show up in time: go on with those that did."""
        if not self.ready:
            self.ready = self.dirty = True

    def owns(self, region: str) -> bool:
        return shard_of(region, self.cfg.shards) in self.shards

    def owns_tile(self, key: TileKey, tile_size_m: float) -> bool:
        """A road-map tile is this server's to write: its region is one of this server's now."""
        return self.owns(region_of_tile(key, tile_size_m, self.cfg))

    def tile_writers(self, key: TileKey, tile_size_m: float) -> set[str] | None:
        """The server whose tile this is (the owner of its region among the live servers), whose
        copies of it others take; None (anyone's) within MOVE_GRACE_S of a change of the live
        servers or of the start, while the views of who owns what may differ."""
        if time.monotonic() - self.servers_changed_at < MOVE_GRACE_S:
            return None
        shard = shard_of(region_of_tile(key, tile_size_m, self.cfg), self.cfg.shards)
        writer = owner(shard, self.servers | {self.me})
        return set() if writer is None else {writer}

    def own_copy(self, key: str) -> bool:
        """A copy for a region near the vehicle's own, when this server also owns the vehicle's
        own region: it hears the message itself on its home key, so the copy is skipped."""
        where = KeySpace.region_of_node_key(key)
        return where is not None and where[1] != where[2] and self.owns(where[2])

    def saw_node(
        self,
        vehicle_id: str,
        key: str,
        now: float,
        t: GpsTime,
        position: tuple[float, float, float] | None = None,
    ) -> None:
        """Remember the vehicle's own region at its epoch `t` (the key names it), and whether its
        next message will come here too: its region is ours, or its fix (`position`) is well
        inside the copy margin of one of ours, so one more epoch of driving keeps it there."""
        self.version += 1
        if vehicle_id not in self.heard:
            self.heard.add(vehicle_id)
            self.last_new_speaker = now
        where = KeySpace.region_of_node_key(key)
        if where is None:
            return
        home = where[2]
        if len(self.region_at) < REGION_AT_MAX:
            self.region_at[vehicle_id, t] = home
        old = self.region.get(vehicle_id)
        if old is None or not t < self.region_t.get(vehicle_id, t):
            self.region[vehicle_id] = home
            self.region_t[vehicle_id] = t
            near = self.owns(home) or (
                position is not None and any(self.owns(r) for r in regions_near(position, home, self.inner))
            )
            (self.coming.add if near else self.coming.discard)(vehicle_id)

    # -- subscriptions -------------------------------------------------------------------------
    def wanted(self) -> set[str]:
        """Node key expressions to hear: every owned shard (once the expected servers are seen)."""
        if not self.ready:
            return set()
        return {self.keys.shard_nodes(s) for s in self.shards}

    def sync(self, node: BusNode) -> None:
        """Make the node's node-key subscriptions what `wanted` says, with history: a server
        taking a shard over first gets what the agents' caches hold."""
        if not self.dirty:
            return
        self.dirty = False
        if self.ready and self.ready_at is None:
            self.ready_at = time.monotonic()
        want = self.wanted()
        have = {k for k in node.subscriptions if "/shard/" in k}
        for k in sorted(have - want):
            node.unsubscribe(k)
        for k in sorted(want - have):
            node.subscribe(Subscription(k, history=True))

    # -- solving -------------------------------------------------------------------------------
    def select(
        self, t: GpsTime, msgs: Mapping[str, NodeMessage], pairs: Iterable[tuple[str, str]]
    ) -> Selection:
        """What this server solves at `t` and whom it answers for (docs/scale.md, "Boundaries").

        A vehicle is answered by exactly one server: the owner of the region it was in at `t`
        (its home key names it; every server computes the same owner). Clusters are the vehicles
        linked by ranges within the window (`RangeGraph`; `pairs`: the ranges the estimator gets at
        `t`, `FusionStep.epoch_ranges`). Every cluster with at least one vehicle of this server's
        regions is solved here whole, with the copies of the other regions' vehicles it heard,
        so the ranges across a boundary are kept on both sides; a cluster with none is left to
        the others. A boundary cluster is thus solved by each server it touches (the price of
        needing no agreement on who owns it), and each answers only for its own vehicles.

        Also tried (docs/scale.md): solving the clusters of other regions' vehicles within 150 or
        500 m of this server's regions, so that a crossing vehicle arrives with a window here.
        It made the hand-over worse, not better: such a track starts from a seed earlier and
        drifts from its owner's for longer than one seeded at the crossing."""
        self.graph.add(t, pairs)
        self.version += 1
        solve: dict[str, NodeMessage] = {}
        answer: set[str] = set()
        others: list[str] = []
        for members in self.graph.clusters(msgs):
            own = {v for v in members if (r := self.home_at(v, t)) is not None and self.owns(r)}
            if own:
                solve.update({v: msgs[v] for v in members})
                answer |= own
                self.counts["solved-for-others"] += len(members) - len(own)
            others.extend(v for v in members if v not in own)
        self.counts["left-to-other-server"] += len(others)
        self.solving = answer
        for k in [k for k in self.region_at if not t < k[1]]:
            del self.region_at[k]
        return Selection(solve, answer, others)

    def home_at(self, vehicle_id: str, t: GpsTime) -> str | None:
        """The vehicle's own region at its epoch `t` (else at its latest epoch heard)."""
        return self.region_at.get((vehicle_id, t), self.region.get(vehicle_id))

    def awaited(
        self,
        live: set[str],
        upcoming: Mapping[str, NodeMessage],
        t: GpsTime | None = None,
        interval_s: float = 1.0,
    ) -> set[str]:
        """The live vehicles a lockstep server waits for: those in its regions; those linked to
        them by ranges (in the window, or in the messages of the epoch to solve), whose cluster it
        may own; and those heard at the previous epoch whose next message will come here too (in
        the copy margin of its regions, `saw_node`), such as a vehicle about to cross. Only the first are waited for
        as long as any vehicle (`Pacing`); the others briefly, as their message may go elsewhere,
        and not at all once another server answered them at `t` (they moved on)."""
        key = (self.version, len(live), len(upcoming), t)
        if self._awaited is not None and self._awaited[0] == key:
            return self._awaited[1]  # unchanged since the last call (the server asks every loop)
        out = self._awaited_now(live, upcoming, t, interval_s)
        self._awaited = (key, out)
        return out

    def _awaited_now(
        self, live: set[str], upcoming: Mapping[str, NodeMessage], t: GpsTime | None, interval_s: float
    ) -> set[str]:
        pairs = set(self.graph.last) | {
            (vid, r.to) if vid < r.to else (r.to, vid) for vid, m in upcoming.items() for r in m.ranges
        }
        linked: dict[str, set[str]] = {}
        for a, b in pairs:
            linked.setdefault(a, set()).add(b)
            linked.setdefault(b, set()).add(a)
        out = self.owned_vehicles(live)
        todo = list(out)
        while todo:
            for n in linked.get(todo.pop(), ()):
                if n not in out and n in live and n in self.coming:
                    out.add(n)
                    todo.append(n)
        if t is not None:
            since = t + (-1.5 * interval_s)
            out |= {
                v for v in self.coming & live if (tv := self.region_t.get(v)) is not None and not tv < since
            }
            out = {v for v in out if not self._answered_elsewhere(v, t)}
        return out

    def surely_awaited(self, vehicle_id: str, t: GpsTime) -> bool:
        """Whether `awaited(live, ..., t)` holds the live vehicle whatever else is upcoming: it is in
        this server's regions and no other server answered it at `t`. Pacing asks this first, as
        `awaited` rebuilds the range links of the window and the epoch (once per message it cost a
        regional server more than GTSAM's updates)."""
        return self._owned(vehicle_id) and not self._answered_elsewhere(vehicle_id, t)

    def _answered_elsewhere(self, vehicle_id: str, t: GpsTime) -> bool:
        """Another server answered the vehicle at `t` or later (it moved on: not awaited here)."""
        ta = self.answered_elsewhere.get(vehicle_id)
        return ta is not None and not ta < t

    def mine(self, vehicle_id: str) -> bool:
        """Whether this server solves the vehicle now: in its regions, or in its last epoch."""
        return vehicle_id in self.solving or bool(self.owned_vehicles((vehicle_id,)))

    def owned_vehicles(self, vehicles: Iterable[str]) -> set[str]:
        """The vehicles among `vehicles` whose last region this server owns (lockstep waits for them)."""
        return {v for v in vehicles if self._owned(v)}

    def _owned(self, vehicle_id: str) -> bool:
        r = self.region.get(vehicle_id)
        return r is not None and self.owns(r)

    # -- hand-over -----------------------------------------------------------------------------
    def peer_solution(self, key: str, sol: SolutionMessage) -> None:
        """Another server's solution: keep each vehicle's latest state as a hand-over seed."""
        if KeySpace.server_of_solution_key(key) in ("", self.me) or sol.server == self.me:
            return
        t = gps_time(sol.epoch)
        self.version += 1
        for vid in sol.answered:
            if len(self.answered_elsewhere) < PEER_STATE_MAX or vid in self.answered_elsewhere:
                old_t = self.answered_elsewhere.get(vid)
                if old_t is None or old_t < t:
                    self.answered_elsewhere[vid] = t
        for v in sol.vehicles:
            old = self.peer_state.get(v.vehicle_id)
            if old is None or old[0] < t:
                if old is None and len(self.peer_state) >= PEER_STATE_MAX:
                    self.counts["peer-state-full"] += 1
                    continue
                self.peer_state[v.vehicle_id] = (t, v)

    def seeds(self, vehicles: Iterable[str], tracked: Iterable[str]) -> list[VehicleSeed]:
        """Seeds for the vehicles this server is about to solve but does not track yet."""
        known = set(tracked)
        out: list[VehicleSeed] = []
        for vid in sorted(set(vehicles) - known):
            got = self.peer_state.get(vid)
            if got is None:
                self.counts["handover-without-seed"] += 1  # no other server solved it yet
                continue
            t, v = got
            cov = None if v.covariance_m2 is None else np.array(v.covariance_m2, dtype=float).reshape(3, 3)
            out.append(VehicleSeed(vid, t, np.array(v.position_ecef_m), cov, dict(v.clocks_s)))
        self.counts["handover-seeds"] += len(out)
        return out

    def summary(self) -> dict[str, list[str]]:
        """Owned regions -> their vehicles (for diagnostics and the API)."""
        out: dict[str, list[str]] = {}
        for vid, r in sorted(self.region.items()):
            if self.owns(r):
                out.setdefault(r, []).append(vid)
        return out

    def diagnostics(self) -> dict[str, Any]:
        """The region fields of the server's diagnostics message: who it is, what it owns."""
        return {
            "server": self.me,
            "servers": sorted(self.servers),
            "shards": sorted(self.shards),
            "regions": self.summary(),
            "region_counts": dict(sorted(self.counts.items())[:64]),
        }
