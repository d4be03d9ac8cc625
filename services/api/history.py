"""The API's own solution log: what it accepted survives a crash of the API.

Every solution the `FleetState` takes is appended (SQLite, `coplane.store.SolutionLog`) with the
time it was received; on start, before the bus is subscribed, the log is replayed through the same
`FleetState.on_solution` with those receive times, so tracks, latest states, plane counts and
accuracy after a restart equal those before it (docs/reliability/durability.md). The log keeps
the last `keep` solutions (the longest of the track and accuracy windows; pruned on start and
every `PRUNE_EVERY` appends), so it and the start-up replay stay bounded; all-time accuracy
figures then cover that many epochs after a restart.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any

from coplane.messages import SolutionMessage
from coplane.store import SolutionLog, log_path

from .settings import ApiSettings
from .state import FleetState

log = logging.getLogger("coplane.api")

PRUNE_EVERY = 3_600  # appends between two prunes of the log to its last `keep` solutions


class ApiHistory:
    """The log of solutions the API took, and the hook that records them."""

    def __init__(self, path: Path, keep: int) -> None:
        self.log = SolutionLog(path, synchronous="NORMAL")
        self.keep = keep
        self.failed = 0
        self.appends = 0

    def load(self, state: FleetState) -> int:
        """Replay the logged solutions of this fleet into `state`; returns how many were taken."""
        self.log.prune(self.keep)
        n = 0
        for row in self.log.rows(fleet=state.fleet):
            n += bool(state.on_solution(row.solution, row.appended_unix_s))
        return n

    def record(self, sol: SolutionMessage, now: float) -> None:
        """Append one taken solution; a failed append is logged and counted, never raised into
        ingestion (the in-memory state stays right, only the next restart would miss it)."""
        try:
            self.log.append(sol, now=now)
            self.appends += 1
            if self.appends % PRUNE_EVERY == 0:
                self.log.prune(self.keep)
        except Exception:
            self.failed += 1
            log.exception("API history append failed", extra={"seq": sol.seq})

    def attach(self, state: FleetState) -> None:
        """From now on, every solution `state` takes is recorded (wraps its `on_solution`)."""
        take = state.on_solution

        def on_solution(sol: SolutionMessage, now: float, *args: Any, **kwargs: Any) -> bool:
            taken = take(sol, now, *args, **kwargs)
            if taken:
                self.record(sol, now)
            return taken

        state.on_solution = on_solution  # type: ignore[method-assign]

    def close(self) -> None:
        self.log.close()


def open_history(settings: ApiSettings, state: FleetState) -> ApiHistory | None:
    """The API's log (`db`: auto, none or a path), loaded into `state` and recording from now on;
    None when disabled."""
    path = log_path(settings.db, "api", state.fleet, connect=settings.connect)
    if path is None:
        return None
    t0 = time.perf_counter()
    h = ApiHistory(path, keep=max(settings.history_per_vehicle, settings.accuracy_window))
    n = h.load(state)
    h.attach(state)
    log.info(
        "history loaded",
        extra={"log": str(path), "solutions": n, "seconds": round(time.perf_counter() - t0, 3)},
    )
    return h


def check_history(settings: ApiSettings, fleet: str) -> None:
    """Fail now, named (`StoreError`), when the log the settings name is corrupt or foreign: before
    uvicorn starts, so the user gets one line and exit code 2 instead of a lifespan traceback."""
    path = log_path(settings.db, "api", fleet, connect=settings.connect)
    if path is not None and path.is_file():
        SolutionLog(path, writer=False).close()
