"""The fusion server's durability: every solution is in its SQLite log before it is published, and a
server restarted after a crash resumes from that log (docs/reliability/durability.md).

Resume happens only when the previous server of this fleet and method did not stop cleanly (the
log's `writer` entry is still `open`) and its last solution is recent (`resume_max_age_s`): a clean
stop (SIGTERM, end of a replay) means the next start is a new run. Resuming continues `seq`, the
solved-epoch count and the per-vehicle counters, never re-solves an epoch at or before the last
logged one, and seeds each vehicle's estimator state from its last logged solution (estimators that
cannot take seeds start afresh). If the crash came between a commit and its publication, lockstep
agents wait for that solution forever: so when, `REPUBLISH_AFTER_S` after the resume, agents are
live but no newer epoch has arrived, the last logged solution is published once more (consumers
drop a repeated epoch). Epochs missed while
the server was down are solved from the node messages the agents' publication caches replay to its
history subscription (`coplane.bus.Subscription(history=True)`), as far as those caches reach.
The log keeps the last `KEEP_SOLUTIONS` solutions (pruned on start and every `PRUNE_EVERY`
appends): resuming needs only the newest.
"""

from __future__ import annotations

import logging
import secrets
import sys
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from coplane.bus import BusNode, encode
from coplane.estimation.contract import VehicleSeed, seed_estimator
from coplane.messages import SolutionMessage
from coplane.steps import gps_time
from coplane.store import SolutionLog, StoredSolution, log_path

if TYPE_CHECKING:
    from .server import FusionServer

log = logging.getLogger("coplane.fusion_server")

REPUBLISH_AFTER_S = 3.0  # lockstep agents resend every second (agent `resend_s`)
KEEP_SOLUTIONS = 86_400  # the log keeps the last day at 1 Hz; resuming needs only the newest
PRUNE_EVERY = 3_600  # appends between two prunes


@dataclass(frozen=True)
class Resumed:
    """What a restarted server took over from its log."""

    last: StoredSolution
    seeds: int  # vehicles whose state the estimator was seeded with
    age_s: float  # wall seconds since the last solution was committed


class Durability:
    """The server's solution log; `None` path: durability off (every method is then a no-op)."""

    def __init__(self, path: Path | None, fleet: str, method: str, resume_max_age_s: float = 300.0) -> None:
        self.path = path
        self.fleet = fleet
        self.method = method
        self.resume_max_age_s = resume_max_age_s
        self.log: SolutionLog | None = None  # opened by `start`, so building a server does no I/O
        self.resumed: Resumed | None = None
        self.failed = 0  # appends that failed (their solutions were not published)
        self.republished = False
        self.appends = 0
        self._republish_at: float | None = None

    @staticmethod
    def new_generation() -> str:
        """A fresh server generation: 16 random hex digits. Consumers reset their state only when
        it changes, so a crash + resume (which keeps the logged one) is not a new run for them."""
        return secrets.token_hex(8)

    @classmethod
    def for_server(cls, server: FusionServer) -> Durability:
        """The log the settings name (`db`: auto, none, or a path), not opened yet."""
        s = server.s
        parts = ("fusion", server.fleet, server.spec.name, *((s.server_id,) if s.regions else ()))
        path = log_path(s.db, *parts, connect=s.connect)  # one log per server of a regional fleet
        if path is not None and path.is_file():
            SolutionLog(path, writer=False).close()  # a corrupt or foreign file fails now, named
        return cls(path, server.fleet, server.spec.name, s.resume_max_age_s)

    def start(self, server: FusionServer, now: float | None = None) -> None:
        """Open the log and resume from it if the last server crashed (called once the bus is up,
        before the first event is handled)."""
        if self.path is not None and self.log is None:
            self.log = SolutionLog(self.path)
            self.log.prune(KEEP_SOLUTIONS)
            if self.resume(server) is not None:
                self._republish_at = (time.monotonic() if now is None else now) + REPUBLISH_AFTER_S

    # -- start ---------------------------------------------------------------------------------
    def resume(self, server: FusionServer, now: float | None = None) -> Resumed | None:
        """Take over the previous server's state if it crashed recently; mark the log open."""
        lg = self.log
        if lg is None:
            return None
        now = time.time() if now is None else now
        crashed = lg.meta("writer") == "open"
        last = lg.last(self.fleet, self.method) if crashed else None
        if last is not None and now - last.appended_unix_s <= self.resume_max_age_s:
            self.resumed = self._take_over(server, lg, last, now)
        elif crashed:
            log.info("solution log not resumed: last solution too old", extra={"log": str(lg.path)})
        lg.set_meta(writer="open", opened_unix_s=now)
        return self.resumed

    def _take_over(self, server: FusionServer, lg: SolutionLog, last: StoredSolution, now: float) -> Resumed:
        sol = last.solution
        server.step.seq = sol.seq + 1
        server.solved_up_to = gps_time(sol.epoch)
        _restore_counters(server, lg.meta("server", {}), lg.path)
        gen = getattr(sol, "generation", None)
        if gen is not None and hasattr(server, "generation"):
            server.generation = gen  # a resumed server is the same generation, not a new one
        seeds = []
        for vid, row in lg.last_per_vehicle(self.fleet, self.method).items():
            vs = next(v for v in row.solution.vehicles if v.vehicle_id == vid)
            cov = None if vs.covariance_m2 is None else np.array(vs.covariance_m2, dtype=float).reshape(3, 3)
            seeds.append(
                VehicleSeed(
                    vid, gps_time(row.solution.epoch), np.array(vs.position_ecef_m), cov, dict(vs.clocks_s)
                )
            )
        n = seed_estimator(server.step.estimator, seeds)
        r = Resumed(last, n, now - last.appended_unix_s)
        log.info(
            "resumed from the solution log",
            extra={"log": str(lg.path), "seq": sol.seq, "epochs_solved": server.epochs_solved, "seeded": n},
        )
        return r

    def tick(self, server: FusionServer, node: BusNode, key: str, now: float | None = None) -> None:
        """Called every loop: once, `REPUBLISH_AFTER_S` after a resume, publish the last logged
        solution again if live agents are still waiting for it (nothing newer has arrived)."""
        if self._republish_at is None or (time.monotonic() if now is None else now) < self._republish_at:
            return
        self._republish_at = None
        assert self.resumed is not None
        last = self.resumed.last.solution
        t = gps_time(last.epoch)
        progressed = server.solved_up_to != t or any(t < p for p in server.pending)
        if server.live and not progressed:
            node.put(key, encode(last))
            self.republished = True
            log.info("republished the last logged solution", extra={"seq": last.seq})

    # -- each solution -------------------------------------------------------------------------
    def commit(self, server: FusionServer, sol: SolutionMessage) -> bytes | None:
        """The payload to publish, once the solution and the server's counters are committed; None
        if the log failed (the solution is then not published: nothing goes out that is not on disk)."""
        gen = getattr(server, "generation", None)
        if gen is not None and sol.generation != gen:
            sol = sol.model_copy(update={"generation": gen})  # every solution names its server run
        payload = encode(sol)
        if self.log is None:
            return payload
        snap = {
            "epochs_solved": server.epochs_solved,
            "node_payloads": server.node_payloads,
            "last_solve_s": server.last_solve_s,
            "counters": {v: dict(c) for v, c in server.counters.items()},
            "rejected": dict(server.rejected_by_reason),
        }
        try:
            self.log.append(sol, payload, meta={"server": snap})
            self.appends += 1
            if self.appends % PRUNE_EVERY == 0:
                self.log.prune(KEEP_SOLUTIONS)
        except Exception:
            self.failed += 1
            log.exception("solution log append failed; solution not published", extra={"seq": sol.seq})
            return None
        return payload

    def publish(self, server: FusionServer, node: BusNode, key: str, sol: SolutionMessage) -> None:
        """Commit, then publish (the server's one way to put a solution)."""
        payload = self.commit(server, sol)
        if payload is not None:
            node.put(key, payload)

    # -- stop ----------------------------------------------------------------------------------
    def close(self) -> None:
        """Close the log. Called from the server's `finally`: a clean stop marks the log closed (the
        next server of this fleet starts a new run); an exception on its way out leaves it open, so
        a restart resumes as after a crash."""
        lg, self.log = self.log, None
        if lg is None:
            return
        try:
            if sys.exc_info()[0] is None:
                lg.set_meta(writer="closed", closed_unix_s=time.time())
        finally:
            lg.close()


def _restore_counters(server: FusionServer, snap: Any, path: Path) -> None:
    """The diagnostics counters of the crashed run (what `DiagnosticsMessage` reports). A damaged
    snapshot costs only them: the server resumes with its counters from zero and says so."""
    try:
        snap = snap or {}
        epochs, payloads = int(snap.get("epochs_solved", 0)), int(snap.get("node_payloads", 0))
        last = snap.get("last_solve_s")
        if last is not None:
            last = float(last)
        counters = {
            vid: Counter({str(k): int(n) for k, n in counts.items()})
            for vid, counts in (snap.get("counters") or {}).items()
            if vid in server.counters
        }
        rejected = Counter({str(k): int(n) for k, n in (snap.get("rejected") or {}).items()})
    except (TypeError, ValueError, AttributeError, ArithmeticError) as exc:
        log.warning(
            "solution log: the counters of the crashed run are unreadable, they start from zero",
            extra={"log": str(path), "error": str(exc)[:200]},
        )
        return
    server.epochs_solved, server.node_payloads, server.last_solve_s = epochs, payloads, last
    server.counters.update(counters)
    server.rejected_by_reason = rejected
