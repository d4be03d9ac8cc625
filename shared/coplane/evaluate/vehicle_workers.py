"""Vehicle steps of an in-process run spread over several cores, in lockstep with the caller.

The fleet's vehicle steps (SPP, Doppler, plane, node message) of one epoch are independent of each
other; only the fusion step joins them. `coplane eval` therefore forks worker processes that each
own some vehicles' `VehicleStep`s, exactly as agent processes do over the bus: every epoch the
caller sends the previous fleet solution and the epoch's DGNSS corrections, the workers answer with
their node messages, and the caller runs its own vehicles and the fusion step meanwhile. Messages
travel pickled (bit-exact floats, no re-validation: the objects were validated when built), so
a run gives the same bits whatever the number of workers.

Written here rather than with concurrent.futures: a pool would pickle each vehicle's step (its
whole plane history) with every task; these workers keep their steps across epochs.
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import os
import traceback
from collections.abc import Callable, Mapping, Sequence
from multiprocessing.connection import Connection
from typing import Any

from coplane.gnss.dgnss import DgnssCorrections
from coplane.messages import NodeMessage, SolutionMessage
from coplane.steps import VehicleStep

# (index into the schedule, that epoch's corrections, the previous epoch's solution)
Request = tuple[int, DgnssCorrections | None, SolutionMessage | None]
# builds the node messages of the given steps for schedule index k (the caller's own loop body)
EpochFn = Callable[[Mapping[str, VehicleStep], int, DgnssCorrections | None], dict[str, NodeMessage]]


def default_jobs(n_vehicles: int) -> int:
    """Processes for the vehicle steps: the cores this process may use, at most one per vehicle."""
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        cores = os.cpu_count() or 1
    return max(1, min(cores, n_vehicles))


def split_vehicles(ids: Sequence[str], jobs: int) -> list[list[str]]:
    """Vehicles dealt round-robin to `jobs` groups; group 0 stays in the calling process."""
    groups = [list(ids[k::jobs]) for k in range(jobs)]
    return [g for g in groups if g]


def _serve(conn: Connection, steps: Mapping[str, VehicleStep], epoch_fn: EpochFn) -> None:
    try:
        while (req := conn.recv()) is not None:
            k, corr, prev = req
            if prev is not None:
                for s in steps.values():
                    s.ingest(prev)
            conn.send(("ok", epoch_fn(steps, k, corr)))
    except EOFError:  # the caller went away
        return
    except BaseException:
        conn.send(("error", traceback.format_exc()))


class VehicleWorkers:
    """Worker processes, each owning a group of vehicle steps; use as a context manager.

    Forked (the steps, the recording and `epoch_fn` are inherited, nothing is pickled up front),
    so this needs a platform with fork; `available()` says whether it has one.
    """

    def __init__(self, groups: Sequence[Mapping[str, VehicleStep]], epoch_fn: EpochFn) -> None:
        ctx = mp.get_context("fork")
        self._conns: list[Connection] = []
        self._procs: list[Any] = []
        for steps in groups:
            parent, child = ctx.Pipe()
            p = ctx.Process(target=_serve, args=(child, steps, epoch_fn), daemon=True)
            p.start()
            child.close()
            self._conns.append(parent)
            self._procs.append(p)

    @staticmethod
    def available() -> bool:
        return "fork" in mp.get_all_start_methods()

    def submit(self, k: int, corrections: DgnssCorrections | None, previous: SolutionMessage | None) -> None:
        """Start epoch `k` in every worker (returns at once)."""
        req: Request = (k, corrections, previous)
        for c in self._conns:
            c.send(req)

    def collect(self) -> dict[str, NodeMessage]:
        """The node messages of the epoch last submitted, from every worker."""
        out: dict[str, NodeMessage] = {}
        for c, p in zip(self._conns, self._procs, strict=True):
            try:
                status, payload = c.recv()
            except EOFError:
                raise RuntimeError(f"vehicle worker {p.pid} died (exit code {p.exitcode})") from None
            if status != "ok":
                raise RuntimeError(f"vehicle worker {p.pid} failed:\n{payload}")
            out.update(payload)
        return out

    def close(self) -> None:
        for c in self._conns:
            with contextlib.suppress(OSError):  # the worker already ended
                c.send(None)
            c.close()
        for p in self._procs:
            p.join(timeout=5.0)
            if p.is_alive():
                p.terminate()
                p.join()

    def __enter__(self) -> VehicleWorkers:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
