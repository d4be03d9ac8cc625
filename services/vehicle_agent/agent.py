"""Vehicle agent: replays one vehicle of a recording through VehicleStep and talks to the bus.

Lockstep: publish epoch t, wait for the fleet solution of t (resending t every `resend_s`, so a
restarted fusion server picks it up), ingest it, go on with t+1. Realtime: publish on the wall
clock (scaled by `speed`) and ingest whatever solutions have arrived; never block on the server.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from typing import Any

import numpy as np
import zenoh

from coplane.bus import BadMessage, KeySpace, decode, encode, payload_bytes, session_config
from coplane.gnss.epoch_solver import base_corrections
from coplane.gtime import GpsTime
from coplane.messages import NodeMessage, SolutionMessage
from coplane.methods import get_method
from coplane.recording.reader import open_recording
from coplane.replay import base_by_epoch, first_epoch, fleet_id, uwb_for_vehicle, vehicle_schedule
from coplane.steps import VehicleStep, VehicleStepConfig, gps_time

from .settings import AgentSettings

log = logging.getLogger("coplane.agent")


class VehicleAgent:
    def __init__(self, settings: AgentSettings, stop: threading.Event | None = None) -> None:
        self.s = settings
        self.stop = stop or threading.Event()
        rec = open_recording(settings.recording)
        self.rec = rec
        man = rec.manifest
        v = man.vehicle(settings.vehicle_id)
        self.fleet = settings.fleet or fleet_id(man.name)
        self.keys = KeySpace(self.fleet)
        spec = get_method(settings.method)
        uwb_sigma = man.uwb.sigma_m if man.uwb else 0.3
        self.step = VehicleStep(
            self.fleet,
            v.id,
            v.antenna_height_m,
            rec.nav,
            spec,
            VehicleStepConfig(uwb_sigma_m=uwb_sigma, seed=settings.seed),
        )
        self.schedule = vehicle_schedule(rec.vehicle_epochs(v.id), man.interval_s)
        self.use_dgnss = man.base is not None if settings.dgnss is None else settings.dgnss
        # only this vehicle's file, the base and uwb.csv are read: agents start fast
        self.base = base_by_epoch(rec) if self.use_dgnss else {}
        self.uwb = uwb_for_vehicle(rec.uwb(), v.id, (t for t, _ in self.schedule), man.interval_s)
        self.t0 = first_epoch(rec)  # the fleet's first epoch: the realtime origin
        self.skipped = 0
        self.solutions: queue.Queue[bytes] = queue.Queue()
        self.published = 0
        self.ingested = 0
        self.bad_solutions = 0

    def _on_solution(self, sample: Any) -> None:
        self.solutions.put(payload_bytes(sample))

    def _ingest_one(self, payload: bytes) -> SolutionMessage | None:
        try:
            sol = decode(SolutionMessage, payload)
        except BadMessage as exc:
            self.bad_solutions += 1
            log.warning("rejected solution payload", extra={"reason": str(exc)})
            return None
        if sol.fleet != self.fleet:
            return None
        self.step.ingest(sol)
        self.ingested += 1
        return sol

    def _corrections(self, t: GpsTime) -> Any:
        if not self.use_dgnss or self.rec.manifest.base is None:
            return None
        b = self.base.get(t)
        if b is None:
            return None
        return base_corrections(b, np.asarray(self.rec.manifest.base.position_ecef_m), self.rec.nav)

    def run(self) -> int:
        """Replay the whole schedule; returns the number of node messages published."""
        s = self.s
        session = zenoh.open(session_config("client", s.connect, lease_ms=s.lease_ms))
        token = session.liveliness().declare_token(self.keys.alive("agent", self.step.vehicle_id))
        pub = session.declare_publisher(
            self.keys.node(self.step.vehicle_id),
            congestion_control=zenoh.CongestionControl.BLOCK,
            reliability=zenoh.Reliability.RELIABLE,
        )
        session.declare_subscriber(self.keys.solution, self._on_solution)
        log.info(
            "agent started",
            extra={"vehicle": self.step.vehicle_id, "epochs": len(self.schedule), "pace": s.pace},
        )
        try:
            if not self.schedule:
                return 0
            start = s.start_unix_s if s.start_unix_s is not None else time.time()
            t0 = self.t0 or self.schedule[0][0]
            interval = self.rec.manifest.interval_s
            for t, ep in self.schedule:
                if self.stop.is_set():
                    break
                if s.pace == "realtime":
                    due = start + (t - t0) / s.speed
                    if due < time.time() - interval / s.speed:
                        self.skipped += 1  # already past: a (re)started agent joins at the current epoch
                        continue
                    if self.stop.wait(max(0.0, due - time.time())):
                        break
                while True:  # ingest what has arrived, in order
                    try:
                        self._ingest_one(self.solutions.get_nowait())
                    except queue.Empty:
                        break
                msg = self.step.process(t, ep, self._corrections(t), self.uwb.get(t, ()))
                msg = msg.model_copy(update={"sent_unix_s": time.time()})  # latency stamp only
                payload = encode(msg)
                pub.put(payload)
                self.published += 1
                if s.pace == "lockstep":
                    self._wait_for_solution(t, pub, payload, msg)
            log.info(
                "agent finished",
                extra={"vehicle": self.step.vehicle_id, "published": self.published, "skipped": self.skipped},
            )
            return self.published
        finally:
            token.undeclare()
            session.close()

    def _wait_for_solution(self, t: GpsTime, pub: Any, payload: bytes, msg: NodeMessage) -> None:
        last_send = time.monotonic()
        while not self.stop.is_set():
            try:
                sol = self._ingest_one(self.solutions.get(timeout=0.05))
            except queue.Empty:
                sol = None
                if time.monotonic() - last_send > self.s.resend_s:
                    pub.put(payload)  # the server dedups; a restarted server needs it
                    last_send = time.monotonic()
            if sol is not None and not (gps_time(sol.epoch) < t):
                return
