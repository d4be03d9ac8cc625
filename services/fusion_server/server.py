"""Fusion server: assembles epochs from node messages and solves them with FusionStep.

Every received payload ends in exactly one bucket per vehicle: used, rejected (invalid), late
(its epoch was already solved), or duplicate; payloads that name no known vehicle are counted by
reason only (so hostile ids cannot grow memory). Membership follows Zenoh liveliness tokens.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import Counter, defaultdict

from coplane.bus import (
    BadMessage,
    BusEvent,
    BusNode,
    KeySpace,
    Payload,
    Presence,
    Publication,
    RepeatDecoder,
    Request,
    Subscription,
    current_security,
    decode,
    encode,
    session_config,
)
from coplane.bus.security import check_server_identity
from coplane.estimation.contract import seed_estimator
from coplane.gtime import GpsTime
from coplane.messages import DiagnosticsMessage, NodeMessage, SolutionMessage, VehicleCounters
from coplane.parallel import smoothers_for
from coplane.recording.manifest import load_manifest
from coplane.replay import replay_setup
from coplane.runtime import RateLimitedLog
from coplane.steps import epoch_time, gps_time
from coplane.store import map_path

from .admission import Admission, AdmissionConfig
from .durability import Durability
from .pacing import Pacing
from .regions import RegionRole
from .road_map import LiveRoadMap
from .settings import FusionSettings

log = logging.getLogger("coplane.fusion_server")
# bus events handled before the pacing looks again (a lockstep epoch of 1000 vehicles: 4 looks)
EVENT_BATCH = 256


class FusionServer(Pacing):
    def __init__(self, settings: FusionSettings, stop: threading.Event | None = None) -> None:
        self.s = settings
        self.stop = stop or threading.Event()
        man = load_manifest(settings.recording)
        self.known = {v.id for v in man.vehicles}
        setup = replay_setup(
            man,
            settings.method,
            seed=settings.seed,
            interruption=settings.interruption_rate,
            dgnss=False,  # corrections are the vehicles' business; the server never reads the base
            fleet=settings.fleet,
        )
        self.fleet = setup.fleet
        self.keys = KeySpace(self.fleet)
        self.spec = setup.method
        self.step = setup.fusion_step(smoothers_for(setup.method.fgo, settings.cluster_workers))
        self.pending: dict[GpsTime, dict[str, NodeMessage]] = defaultdict(dict)
        self.first_arrival: dict[GpsTime, float] = {}
        self.last_arrival: dict[GpsTime, float] = {}  # lockstep: an epoch still coming in
        self.latest: dict[str, GpsTime] = {}
        self.node_decoder = RepeatDecoder(NodeMessage)
        self.solved_up_to: GpsTime | None = None
        self.live: set[str] = set()
        self.counters: dict[str, Counter[str]] = {v: Counter() for v in self.known}
        self.rejected_by_reason: Counter[str] = Counter()
        self.epochs_solved = 0
        self.node_payloads = 0
        self.last_solve_s: float | None = None
        self.started = time.monotonic()
        self.waiting_since: float | None = None
        self.admission = Admission(
            AdmissionConfig(
                interval_s=man.interval_s,
                max_ahead_s=settings.max_ahead_s,
                max_pending_epochs=settings.max_pending_epochs,
                rate_per_s=settings.rate_limit_per_s,
                rate_per_epoch=settings.rate_limit_per_epoch,
                burst=settings.rate_limit_burst,
                silent_after_s=settings.stall_timeout_s,
                spp_residual_m=settings.spp_residual_max_m,
                plane_tilt_deg=settings.plane_tilt_max_deg,
                plane_distance_m=settings.plane_distance_max_m,
                plane_policy=settings.plane_policy,
            )
        )
        self.reject_log = RateLimitedLog(log, settings.reject_log_every_s)
        self.generation = Durability.new_generation()  # this run; a resume keeps the logged one
        self.durable = Durability.for_server(self)  # the solution log (opened by run)
        self.heights = {v.id: v.antenna_height_m for v in man.vehicles}
        self.road_map: LiveRoadMap | None = None  # opened by run (settings.map)
        self.regions: RegionRole | None = None  # one of several servers of the fleet (docs/scale.md)
        if settings.regions:
            window = int(getattr(getattr(self.step.estimator, "config", None), "window_epochs", 10))
            self.regions = RegionRole(
                settings.server_id,
                self.keys,
                settings.region_config(),
                window * man.interval_s,
                settings.expected_servers,
            )
        # with regions the keys name the server, which its own identity is held to (docs/bus.md)
        own = self.keys.server_keys(settings.server_id if settings.regions else None)
        self.solution_key, self.diagnostics_key, self.tiles_key = own.solution, own.diagnostics, own.tiles

    def node(self) -> BusNode:
        """The server's place on the bus: every vehicle's node key and the agents' tokens in,
        solutions and diagnostics out."""
        if self.regions is not None:  # node keys follow the shards owned (RegionRole.sync)
            listen = [
                Subscription(self.keys.all_alive("fusion"), liveliness=True),
                Subscription(self.keys.all_solutions),  # the other servers': hand-over seeds
                # the other servers' map tiles, their caches too (docs/scale.md)
                *([Subscription(self.keys.all_map_tiles, history=True)] if self.road_map is not None else []),
            ]
        else:
            listen = [Subscription(self.keys.all_nodes, history=True)]  # agents' caches, after a restart
        return BusNode(
            session_config("client", self.s.connect, lease_ms=self.s.lease_ms),
            token=self.keys.alive("fusion", self.s.server_id),
            publish=[
                Publication(self.solution_key, must_deliver=True),
                # reliable too: the final diagnostics are put just before the session closes, and a
                # dropped one leaves consumers with stale counters (it is one message a second)
                Publication(self.diagnostics_key, must_deliver=True),
                # the road map's tiles, cached for agents that start later (docs/roadmap.md)
                *(
                    [Publication(self.tiles_key, must_deliver=True, history=self.road_map.cache_size)]
                    if self.road_map is not None
                    else []
                ),
            ],
            subscribe=[*listen, Subscription(self.keys.all_alive("agent"), liveliness=True)],
            serve=[self.tiles_key] if self.road_map is not None else [],  # agents' area queries
        )

    # -- message handling ----------------------------------------------------------------------
    def handle(self, event: BusEvent) -> None:
        """The one dispatch of bus events; a bad event is logged and never stops the server."""
        try:
            if isinstance(event, Payload):
                if (tiles_from := KeySpace.server_of_tiles_key(event.key)) is not None:
                    if self.road_map is not None:  # regions: the other servers' tiles
                        self.road_map.take_peer(event.data, tiles_from)
                elif self.regions is not None and KeySpace.vehicle_of_node_key(event.key) is None:
                    self.handle_peer_solution(event.key, event.data)
                else:
                    self.handle_node(event.key, event.data)
            elif isinstance(event, Presence):
                self.handle_alive(event.key, event.alive)
            elif isinstance(event, Request) and self.road_map is not None:
                self.road_map.enqueue(event, self.tiles_key)  # answered between solves
        except Exception:
            log.exception("event handling failed")

    def handle_peer_solution(self, key: str, payload: bytes) -> None:
        """Regions: another server's solution, kept for hand-over seeds (a bad one is counted)."""
        assert self.regions is not None
        try:
            sol = decode(SolutionMessage, payload)
        except BadMessage as exc:
            self.rejected_by_reason[f"peer-solution-{exc.kind}"] += 1
            return
        if sol.fleet == self.fleet:
            self.regions.peer_solution(key, sol)

    def handle_node(self, key: str, payload: bytes, now: float | None = None) -> None:
        """One node payload: decoded, then admitted into `pending` only if `Admission` lets it in
        (docs/bus.md, Admission); every payload ends in exactly one counter bucket."""
        now = time.monotonic() if now is None else now
        self.node_payloads += 1
        vid = KeySpace.vehicle_of_node_key(key)
        if vid is None or vid not in self.known:
            self._reject(None, "unknown-vehicle", key[:120])
            return
        if self.regions is not None and self.regions.own_copy(key):
            self.regions.counts["own-copies"] += 1  # heard on its home key too
            return
        c = self.counters[vid]
        c["received"] += 1
        try:
            msg, digest = self.node_decoder.decode(vid, payload)
            if msg.vehicle_id != vid:
                raise BadMessage("key-mismatch", f"message for {msg.vehicle_id!r} on the key of {vid!r}")
            if msg.fleet != self.fleet:
                raise BadMessage("wrong-fleet", f"fleet {msg.fleet!r} != {self.fleet!r}")
        except BadMessage as exc:
            self._reject(vid, exc.kind, str(exc))
            return
        if self.regions is not None:
            # where it is, even if this epoch is late
            self.regions.saw_node(vid, key, now, gps_time(msg.epoch), msg.spp.position_ecef_m)
        t = gps_time(msg.epoch)
        v = self.admission.check(
            msg,
            t,
            digest,
            now,
            solved_up_to=self.solved_up_to,
            pending_epochs=len(self.pending),
            epoch_pending=t in self.pending,
        )
        if v.outcome == "late":
            # regions: an epoch this server passed without solving the vehicle is another's
            mine = self.regions is None or self.regions.mine(vid)
            c["late" if mine else "elsewhere"] += 1
            return
        if v.outcome == "duplicate":
            c["duplicate"] += 1  # an identical re-send (lockstep agents resend every second)
            return
        if v.outcome == "reject" or v.message is None:
            self._reject(vid, v.reason, v.detail or f"epoch {t}")
            return
        if v.plane_dropped:  # plane_policy "drop": the message is used without its plane (counts planes)
            self.rejected_by_reason["plane-dropped"] += 1
            self.reject_log.warning(
                (vid, "plane-dropped"),
                "dropped an implausible plane",
                {"vehicle": vid, "reason": "plane-dropped", "detail": v.detail},
            )
        if vid in self.latest and t < self.latest[vid]:
            c["out_of_order"] += 1  # still usable: its epoch is not solved yet
        self.pending[t][vid] = v.message
        self.first_arrival.setdefault(t, now)
        self.last_arrival[t] = now
        if vid not in self.latest or self.latest[vid] < t:
            self.latest[vid] = t
        self.admission.admitted(vid, t, msg.seq, digest, now)

    def _reject(self, vid: str | None, reason: str, detail: str) -> None:
        """Count a rejected payload (per vehicle when it names a known one) and log it, at most
        once per (vehicle, reason) every `reject_log_every_s`: hostile input never floods the log."""
        if vid is not None:
            self.counters[vid]["rejected"] += 1
        self.rejected_by_reason[reason] += 1
        self.reject_log.warning(
            (vid, reason),
            "rejected node message",
            {"vehicle": vid or "", "reason": reason, "detail": detail[:300]},
        )

    def handle_alive(self, key: str, alive: bool) -> None:
        ident = KeySpace.id_of_alive_key(key)
        if ident is not None and ident[0] == "fusion" and self.regions is not None:
            self.regions.server_presence(ident[1], alive)
            return
        if ident is None or ident[0] != "agent" or ident[1] not in self.known:
            return
        vid = ident[1]
        if alive:
            if vid not in self.live:
                log.info("vehicle online", extra={"vehicle": vid})
            self.live.add(vid)
        else:
            if vid in self.live:
                log.info("vehicle offline", extra={"vehicle": vid})
            self.live.discard(vid)
            self.latest.pop(vid, None)
            self.admission.offline(vid)  # a restarted agent counts its seq from 0 again

    # -- solving (when: pacing.py) -------------------------------------------------------------
    def solve(self, t: GpsTime) -> SolutionMessage | None:
        msgs = self.pending.pop(t)
        self.first_arrival.pop(t, None)
        self.last_arrival.pop(t, None)
        self.admission.solved(t)
        answer: set[str] = set(msgs)
        if self.regions is not None:
            chosen = self.regions.select(t, msgs, self.step.epoch_ranges(t, msgs))
            msgs, answer = chosen.solve, chosen.answer
            for v in chosen.others:
                self.counters[v]["elsewhere"] += 1
            if not answer:
                log.debug("epoch not ours", extra={"epoch": str(t), "messages": len(msgs)})
                self.solved_up_to = t
                return None
            est = self.step.estimator
            tracked = getattr(est, "tracked_at", lambda _t: getattr(est, "tracked_vehicles", []))(t)
            seed_estimator(est, self.regions.seeds(msgs, tracked))
        missing = sorted(v for v in self._live_here() if v not in msgs)
        for v in missing:
            self.counters[v]["missing"] += 1
        try:
            sol = self.step.solve(t, msgs, missing)
        except Exception:  # the estimator must never take the server down
            log.exception("solve failed", extra={"epoch": str(t)})
            for v in msgs:
                self.counters[v]["rejected"] += 1
            self.rejected_by_reason["solve-failed"] += len(msgs)
            self.solved_up_to = t
            return None
        for v in answer:
            self.counters[v]["used"] += 1
        self.solved_up_to = t
        self.last_solve_s = sol.solve_time_s
        self.epochs_solved += 1
        log.debug("epoch solved", extra={"epoch": str(t), "messages": len(msgs), "answered": len(answer)})
        if self.regions is not None:
            # only its regions' vehicles (and its silent ones): the rest of a boundary cluster is
            # answered by their own region's server (docs/scale.md, "Boundaries")
            mine = answer | self.regions.owned_vehicles(missing)
            kept = [v for v in sol.vehicles if v.vehicle_id in mine]
            sol = sol.model_copy(
                update={"server": self.s.server_id, "answered": sorted(answer), "vehicles": kept}
            )
        if self.road_map is not None:
            self.road_map.add(sol, msgs)  # the vehicles it answers for: each pass once
        return sol

    def diagnostics(self) -> DiagnosticsMessage:
        return DiagnosticsMessage(
            fleet=self.fleet,
            method=self.spec.name,
            pace=self.s.pace,
            epochs_solved=self.epochs_solved,
            last_epoch=epoch_time(self.solved_up_to) if self.solved_up_to is not None else None,
            last_solve_time_s=self.last_solve_s,
            vehicles={
                v: VehicleCounters(**{k: int(n) for k, n in c.items()}, online=v in self.live)
                for v, c in sorted(self.counters.items())
            },
            rejected_by_reason=dict(self.rejected_by_reason),
            live_vehicles=sorted(self.live),
            node_payloads=self.node_payloads,
            pending_epochs=len(self.pending),
            pending_limit=self.admission.config.pending_limit,
            cluster_workers=self.step.workers[0],
            cluster_workers_lost=self.step.workers[1],
            generation=self.generation,
            **(self.regions.diagnostics() if self.regions is not None else {}),
            **(self.road_map.diagnostics() if self.road_map is not None else {}),
        )

    def run(self) -> None:
        s = self.s
        check_server_identity(current_security(), s.server_id if s.regions else None)  # start error
        path = map_path(s.map, self.fleet)
        if path is not None:  # before the node: its tile publisher's cache is sized by the map
            self.road_map = LiveRoadMap.for_server(path, s, self.heights, self.fleet, self.regions)
        with self.node() as node:
            log.info(
                "fusion server started", extra={"fleet": self.fleet, "method": self.spec.name, "pace": s.pace}
            )
            last_diag = 0.0
            self.durable.start(self)  # the solution log; resume after a crash
            try:
                while not self.stop.is_set():
                    queries = self.road_map is not None and len(self.road_map.queries) > 0
                    if (event := node.poll() if queries else node.get(timeout=0.02)) is not None:
                        self.handle(event)
                        # what else is queued, before one pacing decision: deciding after every
                        # message costs O(vehicles) each, O(vehicles^2) per epoch
                        for _ in range(EVENT_BATCH - 1):
                            if (event := node.poll()) is None:
                                break
                            self.handle(event)
                    if self.regions is not None:
                        self.regions.sync(node)
                    now = time.monotonic()
                    while (t := self.ready_epoch(now)) is not None:
                        sol = self.solve(t)
                        if sol is not None:
                            self.durable.publish(self, node, self.solution_key, sol)  # committed first
                    self.durable.tick(self, node, self.solution_key)
                    if self.road_map is not None:
                        self.road_map.tick(now)
                        self.road_map.publish(node, self.tiles_key)
                        self.road_map.serve_queries()  # after the ready epochs: a slice at most
                    if now - last_diag > s.diagnostics_period_s:
                        node.put(self.diagnostics_key, encode(self.diagnostics()))
                        last_diag = now
            finally:
                for event in node.drain():  # account for everything that arrived before the stop
                    self.handle(event)
                if self.road_map is not None:
                    self.road_map.close()  # the last passes: committed, then on the bus
                    self.road_map.publish(node, self.tiles_key)
                node.put(self.diagnostics_key, encode(self.diagnostics()))
                log.info(
                    "fusion server stopped",
                    extra={"epochs": self.epochs_solved, "rejected": dict(self.rejected_by_reason)},
                )
                self.durable.close()
                self.step.close()  # the cluster workers, if any
