"""The launcher's own listener: the fleet's solutions and diagnostics, for progress, the accuracy
table and `--out` (the same `MethodRun` the in-process evaluator fills)."""

from __future__ import annotations

import threading
from types import TracebackType

from coplane.bus import (
    BadMessage,
    BusEvent,
    BusNode,
    KeySpace,
    Payload,
    Subscription,
    decode,
    session_config,
)
from coplane.evaluate.runner import MethodRun, record_solution
from coplane.messages import DiagnosticsMessage, SolutionMessage


class Collector:
    """Subscribes to solutions and diagnostics from the moment it is built until `close`.

    Events are handled on Zenoh's thread (recording a solution is quick); read `run` under `lock`.
    """

    def __init__(self, fleet: str, method: str, connect: str) -> None:
        self.keys = KeySpace(fleet)
        self.run = MethodRun(method, 0.0)
        self.lock = threading.Lock()
        self.epochs = 0
        self.diag: DiagnosticsMessage | None = None
        self.bad = 0
        self.node = BusNode(
            session_config("client", [connect]),
            subscribe=[Subscription(self.keys.solution), Subscription(self.keys.diagnostics)],
            sink=self._on_event,
        ).open()

    def _on_event(self, event: BusEvent) -> None:
        if not isinstance(event, Payload):
            return
        if event.key == self.keys.solution:
            self._on_solution(event.data)
        elif event.key == self.keys.diagnostics:
            self._on_diagnostics(event.data)

    def _on_solution(self, payload: bytes) -> None:
        try:
            sol = decode(SolutionMessage, payload)
        except BadMessage:
            self.bad += 1
            return
        with self.lock:
            record_solution(self.run, sol, {})
            self.epochs += 1

    def _on_diagnostics(self, payload: bytes) -> None:
        try:
            self.diag = decode(DiagnosticsMessage, payload)
        except BadMessage:
            self.bad += 1

    def close(self) -> None:
        self.node.close()

    def __enter__(self) -> Collector:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()
