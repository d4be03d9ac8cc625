"""The launcher's own listener: the fleet's solutions and diagnostics, for progress, the accuracy
table and `--out` (the same `MethodRun` the in-process evaluator fills).

With `out`, every solution is also appended, as it arrives, to `out/solutions.sqlite` (a
`coplane.store.SolutionLog`: the wire JSON, committed per solution), so a crash of `coplane fleet`
loses nothing it already received; the CSV files and summaries are still written at the end from
the collected run. SQLite rather than CSV rows with fsync: a transaction is either in the file or
not, so a kill at any instant never leaves a torn last row, and the file is the same format the
fusion server and the API keep (docs/reliability/durability.md).

Only solutions the consumers' `SolutionGate` (one per server, `GateSet`) accepts (`coplane.bus.trust`) are recorded or written:
a forged or implausible solution never reaches the results on disk; `untrusted` counts them.
"""

from __future__ import annotations

import threading
import time
from collections import Counter
from collections.abc import Callable, Iterable
from pathlib import Path
from types import TracebackType

from coplane.bus import (
    BadMessage,
    BusEvent,
    BusNode,
    KeySpace,
    Payload,
    Presence,
    Subscription,
    decode,
    encode,
    session_config,
)
from coplane.bus.gates import MAX_SERVERS, GateSet
from coplane.evaluate.runner import MethodRun, record_solution
from coplane.messages import DiagnosticsMessage, SolutionMessage, merge_diagnostics
from coplane.regions import RegionConfig
from coplane.store import SolutionLog

STREAM_FILE = "solutions.sqlite"


class Collector:
    """Subscribes to solutions and diagnostics from the moment it is built until `close`.

    Events are handled on Zenoh's thread (recording a solution is quick); read `run` under `lock`.
    `regions`: the fleet's region grid when several servers share it (`GateSet`).
    """

    def __init__(
        self,
        fleet: str,
        method: str,
        connect: str,
        out: Path | None = None,
        vehicles: Iterable[str] | None = None,
        listeners: Iterable[Callable[[SolutionMessage], None]] = (),
        regions: RegionConfig | None = None,
    ) -> None:
        self.keys = KeySpace(fleet)
        self.listeners = list(listeners)  # each trusted solution, after it is recorded (NMEA output)
        # one gate per server; with regions each server speaks only of its regions' vehicles
        self.gate = GateSet(fleet, regions=regions, method=method, vehicles=vehicles)
        self.stream: SolutionLog | None = None
        if out is not None:
            path = out / STREAM_FILE
            for old in (path, path.with_name(path.name + "-wal"), path.with_name(path.name + "-shm")):
                old.unlink(missing_ok=True)  # a new run, like the CSV files it rewrites
            self.stream = SolutionLog(path, synchronous="NORMAL")
        self.run = MethodRun(method, 0.0)
        self.lock = threading.Lock()
        self.epochs = 0
        self.diags: dict[str, DiagnosticsMessage] = {}  # the last of each server
        self.bad = 0
        self.node = BusNode(
            session_config("client", [connect]),
            subscribe=[
                Subscription(self.keys.all_solutions),
                Subscription(f"{self.keys.diagnostics}/**"),
                # the servers' tokens: a restarted server's solutions are taken at once (`GateSet`)
                Subscription(self.keys.all_alive("fusion"), liveliness=True),
            ],
            sink=self._on_event,
        ).open()

    def _on_event(self, event: BusEvent) -> None:
        if isinstance(event, Presence):
            self._on_presence(event)
            return
        if not isinstance(event, Payload):
            return
        if event.key.startswith(self.keys.solution):
            self._on_solution(event.data, KeySpace.server_of_solution_key(event.key))
        elif event.key.startswith(self.keys.diagnostics):
            self._on_diagnostics(event.data, event.key.removeprefix(self.keys.diagnostics).lstrip("/"))

    def _on_solution(self, payload: bytes, server: str = "") -> None:
        try:
            sol = decode(SolutionMessage, payload)
        except BadMessage:
            self.bad += 1
            return
        with self.lock:
            taken = self.gate.check(server, sol, time.time()).solution
            if taken is None:
                return  # counted in `untrusted`
            if taken is not sol:  # some vehicles were left out: store what was taken
                sol, payload = taken, encode(taken)
            self._record(sol, payload)
        for listener in self.listeners:
            listener(sol)

    def _on_presence(self, event: Presence) -> None:
        """A fusion server withdrew its token: a restarted server's first solution, held while the
        old run was not over, is taken now."""
        with self.lock:
            sol = self.gate.on_token(event.key, event.alive, time.time())
            if sol is None:
                return
            self._record(sol, encode(sol))
        for listener in self.listeners:
            listener(sol)

    def _record(self, sol: SolutionMessage, payload: bytes) -> None:
        """A trusted solution: on disk first (when streaming), then in the run (lock held)."""
        if self.stream is not None:
            self.stream.append(sol, payload)  # on disk before it counts as received
        record_solution(self.run, sol, {})
        self.epochs += 1

    def _on_diagnostics(self, payload: bytes, server: str = "") -> None:
        if server not in self.diags and len(self.diags) >= MAX_SERVERS:
            self.bad += 1
            return
        try:
            self.diags[server] = decode(DiagnosticsMessage, payload)
        except BadMessage:
            self.bad += 1

    @property
    def diag(self) -> DiagnosticsMessage | None:
        """The fusion server's last diagnostics; with several servers (regions) their sum:
        counters and epochs added, each vehicle as the server that used most of its messages saw
        it."""
        if len(self.diags) <= 1:
            return next(iter(self.diags.values()), None)
        return merge_diagnostics(list(self.diags.values()))

    @property
    def untrusted(self) -> Counter[str]:
        """Solutions (and vehicles in them) the gate did not let through, by reason."""
        return self.gate.counts

    def close(self) -> None:
        try:
            self.node.close()
        finally:
            with self.lock:
                if self.stream is not None:
                    self.stream.close()
                    self.stream = None

    def __enter__(self) -> Collector:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()
