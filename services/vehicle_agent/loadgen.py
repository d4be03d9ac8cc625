"""`coplane loadgen`: many vehicle agents in one process, for load tests (docs/scale.md, "Load").

Each vehicle keeps its own `VehicleStep` (SPP with FDE, Doppler velocity, the plane fit from the
solutions it receives; the history behind the fits is one `SharedHistory`, stored once) and puts
its node messages on its own keys with its own liveliness token, as a `VehicleAgent` does; they share one Zenoh session and one thread, so a 1000-vehicle test needs
one process instead of 1000. Real deployments keep one agent per vehicle, each with its own
certificate: a load generator speaks for every vehicle, so it runs only on an insecure test bus.

Lockstep: every vehicle's epoch t is put, then the generator waits until a solution answered each
of them (re-sending the unanswered after a timeout learnt from the answers' round trips,
`resend.ResendTimer`, at least `resend_s`; giving up after `epoch_timeout_s`), then
t+1. Realtime: epochs are put on the wall clock (`speed`), solutions ingested as they come.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from typing import Any

from coplane.bus import (
    BusNode,
    KeySpace,
    Presence,
    Publication,
    Subscription,
    decode,
    encode,
    session_config,
)
from coplane.bus.codec import BadMessage
from coplane.bus.gates import GateSet
from coplane.gnss.standstill import load_dependencies
from coplane.gtime import GpsTime
from coplane.messages import SolutionMessage
from coplane.recording.model import ObsEpoch, UwbRange
from coplane.recording.reader import open_recording
from coplane.replay import BaseCorrections, replay_setup, uwb_for_vehicle, vehicle_schedule
from coplane.steps import SharedHistory, VehicleStep, gps_time

from .region import RegionKeys
from .resend import MAX_RESEND_S, ResendTimer
from .settings import LoadgenSettings

log = logging.getLogger("coplane.vehicle_agent.loadgen")

SENT_KEPT = 16  # epochs whose send time a vehicle keeps (an answer later than that is not timed)
NODE_HISTORY = 8  # cached node messages per vehicle (1000 vehicles x 120 would be ~400 MB)


@dataclass
class LoadStats:
    """What a load run measured (printed by `coplane loadgen`, read by bench/bench_scale.py)."""

    vehicles: int = 0
    epochs: int = 0
    published: int = 0
    answered: int = 0  # vehicles named as answered in the solutions taken (duplicates included)
    answered_once: int = 0  # published vehicle-epochs answered at least once
    unanswered: int = 0  # lockstep: given up on (realtime: published - answered_once)
    pace: str = "lockstep"
    wall_s: float = 0.0
    front_end_cpu_s: float = 0.0  # SPP, Doppler, planes and encoding of every node message
    ingest_cpu_s: float = 0.0  # solutions into every vehicle's plane history
    latencies_s: list[float] = field(default_factory=list)  # publish -> answering solution
    rejected: Counter[str] = field(default_factory=Counter)
    # lockstep: why each epoch's wait ended (answered / settled / timeout / stopped) and, for the
    # epochs with unanswered vehicles, how many (by epoch index): where a lost epoch is, and why
    await_ends: Counter[str] = field(default_factory=Counter)
    resent: int = 0  # lockstep: node messages put again because their epoch was not answered yet
    unanswered_by_epoch: dict[int, int] = field(default_factory=dict)

    def summary(self) -> dict[str, Any]:
        lat = sorted(self.latencies_s)

        def q(p: float) -> float | None:
            return round(lat[min(len(lat) - 1, int(p * len(lat)))], 4) if lat else None

        if self.pace == "realtime":  # nobody waits: an epoch solved without a vehicle is unanswered
            self.unanswered = self.published - self.answered_once
        solved = self.published - self.unanswered
        return {
            "vehicles": self.vehicles,
            "epochs": self.epochs,
            "published": self.published,
            "solved": solved,
            "unanswered": self.unanswered,
            # answers beyond one per solved vehicle-epoch: a vehicle solved by two servers (both
            # saw its cluster as theirs) or a re-sent message answered again
            "extra_answers": max(0, self.answered - solved),
            "wall_s": round(self.wall_s, 2),
            "vehicle_epochs_per_s": round(solved / self.wall_s, 1) if self.wall_s > 0 else None,
            "front_end_ms_per_vehicle_epoch": round(1e3 * self.front_end_cpu_s / max(1, self.published), 3),
            "ingest_ms_per_vehicle_epoch": round(1e3 * self.ingest_cpu_s / max(1, self.published), 3),
            "latency_p50_s": q(0.5),
            "latency_p99_s": q(0.99),
            "rejected": dict(self.rejected),
            "await_ends": dict(self.await_ends),
            "resent": self.resent,
            "unanswered_by_epoch": {str(i): n for i, n in sorted(self.unanswered_by_epoch.items())},
        }


@dataclass
class _Vehicle:
    step: VehicleStep
    schedule: dict[GpsTime, ObsEpoch | None]
    uwb: dict[GpsTime, list[UwbRange]]
    region: RegionKeys | None
    keys: list[str] = field(default_factory=list)  # where its current epoch went
    payload: bytes = b""
    sent: dict[GpsTime, float] = field(default_factory=dict)  # its last epochs' send times
    answered_t: GpsTime | None = None  # the latest of its epochs a solution answered


class LoadGenerator:
    """Every vehicle of a recording (or the first `vehicles`) on one bus session."""

    def __init__(self, settings: LoadgenSettings, stop: threading.Event | None = None) -> None:
        self.s = settings
        self.stop = stop or threading.Event()
        load_dependencies()  # the standstill test's, now: not at the first standing epoch
        rec = open_recording(settings.recording)
        man = rec.manifest
        setup = replay_setup(man, settings.method, seed=settings.seed, fleet=settings.fleet)
        self.fleet = setup.fleet
        self.keys = KeySpace(self.fleet)
        self.interval = man.interval_s
        ids = [v.id for v in man.vehicles][: settings.vehicles or None]
        self.corrections = BaseCorrections.of(rec, setup.use_dgnss)
        uwb = rec.uwb()
        base = man.base.position_ecef_m if man.base is not None else None
        self.vehicles: dict[str, _Vehicle] = {}
        for vid in ids:
            sched = vehicle_schedule(rec.vehicle_epochs(vid), man.interval_s)
            self.vehicles[vid] = _Vehicle(
                setup.vehicle_step(rec, vid),
                dict(sched),
                uwb_for_vehicle(uwb, vid, (t for t, _ in sched), man.interval_s),
                RegionKeys(self.keys, vid, settings.region_config(), base) if settings.regions else None,
            )
        # one plane history for every vehicle: N histories would store each solution N times
        self.history = SharedHistory(v.step for v in self.vehicles.values())
        self.times = sorted({t for v in self.vehicles.values() for t in v.schedule})
        regions = settings.region_config() if settings.regions else None
        self.gate = GateSet(self.fleet, regions=regions, method=setup.method.name, vehicles=ids)
        self.stats = LoadStats(vehicles=len(ids), pace=settings.pace)
        # re-sends stay well inside an epoch's timeout, so a lost message is sent again before it
        self.resend = ResendTimer(settings.resend_s, min(MAX_RESEND_S, settings.epoch_timeout_s / 3.0))
        self._tokens: list[Any] = []

    def node(self) -> BusNode:
        """One session for every vehicle: their node publishers (or, with regions, added as they
        move), the solutions in."""
        publish = []
        if not self.s.regions:
            publish = [
                Publication(self.keys.node(v), must_deliver=True, history=NODE_HISTORY) for v in self.vehicles
            ]
        return BusNode(
            session_config("client", self.s.connect, lease_ms=self.s.lease_ms),
            publish=publish,
            # the servers' tokens: a restarted server's solutions are taken at once (`GateSet`)
            subscribe=[
                Subscription(self.keys.all_solutions),
                Subscription(self.keys.all_alive("fusion"), liveliness=True),
            ],
            history_later=self.s.regions,
        )

    def run(self) -> LoadStats:
        """Replay every vehicle's schedule; returns what was measured."""
        with self.node() as node:
            self._tokens = [
                node.session.liveliness().declare_token(self.keys.alive("agent", v)) for v in self.vehicles
            ]
            t0 = time.perf_counter()
            start = time.time()
            try:
                for t in self.times:
                    if self.stop.is_set():
                        break
                    if self.s.pace == "realtime":
                        due = start + (t - self.times[0]) / self.s.speed
                        if self.stop.wait(max(0.0, due - time.time())):
                            break
                    self._ingest(node.drain())
                    sent = self._publish(node, t)
                    self.stats.epochs += 1
                    if self.s.pace == "lockstep":
                        self._await(node, t, sent)
                if self.s.pace == "realtime" and not self.stop.is_set():
                    self._await(node, self.times[-1], set(), quiet_s=2.0)
            finally:
                self.stats.wall_s = time.perf_counter() - t0
                for tok in self._tokens:
                    tok.undeclare()
        return self.stats

    def _publish(self, node: BusNode, t: GpsTime) -> set[str]:
        sent: set[str] = set()
        c0 = time.process_time()
        for vid, v in self.vehicles.items():
            if t not in v.schedule:
                continue
            msg = v.step.process(t, v.schedule[t], self.corrections.at(t), v.uwb.get(t, ()))
            msg = msg.model_copy(update={"sent_unix_s": time.time()})
            v.keys = v.region.keys_for(msg, node) if v.region is not None else [self.keys.node(vid)]
            if not v.keys:
                continue
            v.payload = encode(msg)
            v.sent[t] = time.monotonic()
            if len(v.sent) > SENT_KEPT:
                del v.sent[min(v.sent)]
            for key in v.keys:
                node.put(key, v.payload)
            sent.add(vid)
        self.stats.front_end_cpu_s += time.process_time() - c0
        self.stats.published += len(sent)
        return sent

    def _await(self, node: BusNode, t: GpsTime, waiting: set[str], quiet_s: float | None = None) -> None:
        """Lockstep: until every vehicle of `waiting` is answered at `t` (or later), re-sending the
        unanswered after `ResendTimer.timeout_s`, then twice as long each time; realtime end (`quiet_s`): until
        nothing came for that long.

        `settle_s` counts only once some server has answered `t`: before that the servers may
        still be solving it (a 1000-vehicle epoch takes seconds), which is not a reason to go on.
        It is at least as long as the first answer took: with several servers, the others may
        be as busy as the first one was. The back-off keeps re-sent copies from piling up on a
        server that is merely busy."""
        start = time.monotonic()
        deadline = start + (quiet_s if quiet_s is not None else self.s.epoch_timeout_s)
        last_send = start
        last_answer: float | None = None
        settle = self.s.settle_s
        resend_after = self.resend.timeout_s()
        while (waiting or quiet_s is not None) and not self.stop.is_set() and time.monotonic() < deadline:
            ev = node.get(timeout=0.05)
            if ev is None:
                if quiet_s is None and last_answer is not None and time.monotonic() - last_answer > settle:
                    break  # answers stopped coming: the rest were late at their server, count them
                if waiting and time.monotonic() - last_send > resend_after:
                    for vid in sorted(waiting):
                        for key in self.vehicles[vid].keys:
                            node.put(key, self.vehicles[vid].payload)
                    self.stats.resent += len(waiting)
                    last_send = time.monotonic()
                    resend_after *= 2.0
                continue
            if quiet_s is not None:
                deadline = time.monotonic() + quiet_s
            for sol in self._ingest([ev]):
                if not gps_time(sol.epoch) < t:
                    if last_answer is None:
                        settle = max(settle, time.monotonic() - start)
                        self.resend.answered(time.monotonic() - start)
                    last_answer = time.monotonic()
                    waiting -= {v for v in waiting if sol.answers(v)}
        if quiet_s is None:
            if not waiting:
                end = "answered"
            elif self.stop.is_set():
                end = "stopped"
            else:
                end = "timeout" if time.monotonic() >= deadline else "settled"
            self.stats.await_ends[end] += 1
            if waiting:
                self.stats.unanswered_by_epoch[self.stats.epochs - 1] = len(waiting)
                log.warning(
                    "epoch left unanswered",
                    extra={
                        "epoch": str(t),
                        "unanswered": len(waiting),
                        "wait_end": end,
                        "vehicles": ",".join(sorted(waiting)[:8]),
                    },
                )
        self.stats.unanswered += len(waiting)

    def _ingest(self, events: list[Any]) -> list[SolutionMessage]:
        """Gate each solution and feed it to the vehicles' plane history (once: it is shared)."""
        taken: list[SolutionMessage] = []
        c0 = time.process_time()
        now = time.monotonic()
        for ev in events:
            if isinstance(ev, Presence):
                # a fusion server withdrew its token: a restarted server's held solution counts now
                ok = self.gate.on_token(ev.key, ev.alive, time.time())
                if ok is None:
                    continue
            else:
                try:
                    sol = decode(SolutionMessage, ev.data)
                except BadMessage as exc:
                    self.stats.rejected[exc.kind] += 1
                    continue
                ok = self.gate.check(KeySpace.server_of_solution_key(ev.key), sol, time.time()).solution
            if ok is None:
                self.stats.rejected[self.gate.last_reason or "untrusted"] += 1
                continue
            self.history.ingest(ok)
            t = gps_time(ok.epoch)
            for vid in ok.answered or [s.vehicle_id for s in ok.vehicles]:
                w = self.vehicles.get(vid)
                sent_at = w.sent.get(t) if w is not None else None
                if w is not None and sent_at is not None and (w.answered_t is None or w.answered_t < t):
                    w.answered_t = t  # its first answer for t (a later one is a duplicate)
                    self.stats.answered_once += 1
                    self.stats.latencies_s.append(now - sent_at)
            self.stats.answered += len(ok.answered or ok.vehicles)
            taken.append(ok)
        self.stats.ingest_cpu_s += time.process_time() - c0
        return taken
