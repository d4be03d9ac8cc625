"""Vehicle steps of an in-process run on other cores, in lockstep with the fusion step.

The fleet's vehicle steps (SPP, Doppler, plane, node message) of one epoch are independent of each
other; only the fusion step joins them. `coplane eval` therefore forks worker processes that own
the vehicles' `VehicleStep`s, as agent processes do over the bus, while the calling process runs
the fusion step, as the server does. Every epoch the caller sends the previous fleet solution and
the workers answer with their node messages; right after answering, each worker already runs the
GNSS front end (SPP, Doppler: `VehicleStep.front_end`, which does not depend on the fleet) of the
next epoch, while the caller solves this one. Messages travel pickled (bit-exact floats, no
re-validation: they were validated when built), so a run gives the same bits with any number of
workers.

Written here rather than with concurrent.futures: a pool would pickle each vehicle's step (its
whole plane history) with every task; these workers keep their steps across epochs.
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import os
import traceback
from collections.abc import Mapping, Sequence
from multiprocessing.connection import Connection
from typing import Any, Protocol

from coplane.messages import NodeMessage, SolutionMessage
from coplane.steps import VehicleStep

# (index into the schedule, the previous epoch's solution)
Request = tuple[int, SolutionMessage | None]


class EpochWork(Protocol):
    """What a worker does for epoch k of the replay with the vehicle steps it owns."""

    def messages(self, steps: Mapping[str, VehicleStep], k: int) -> dict[str, NodeMessage]:
        """Node messages of epoch k (after the previous solution was ingested)."""
        ...

    def ahead(self, steps: Mapping[str, VehicleStep], k: int) -> None:
        """Work of epoch k that needs nothing from the fleet, done while epoch k-1 is fused."""
        ...


def default_jobs(n_vehicles: int) -> int:
    """Processes for a run: the cores this process may use, at most one per vehicle plus the
    fusion step's."""
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        cores = os.cpu_count() or 1
    return max(1, min(cores, n_vehicles + 1))


def split_vehicles(ids: Sequence[str], workers: int) -> list[list[str]]:
    """Vehicles dealt round-robin to at most `workers` non-empty groups."""
    groups = [list(ids[k::workers]) for k in range(max(1, workers))]
    return [g for g in groups if g]


def _serve(conn: Connection, steps: Mapping[str, VehicleStep], work: EpochWork, n_epochs: int) -> None:
    try:
        work.ahead(steps, 0)
        while (req := conn.recv()) is not None:
            k, prev = req
            if prev is not None:
                for s in steps.values():
                    s.ingest(prev)
            conn.send(("ok", work.messages(steps, k)))
            if k + 1 < n_epochs:
                work.ahead(steps, k + 1)
    except EOFError:  # the caller went away
        return
    except BaseException:
        conn.send(("error", traceback.format_exc()))


class VehicleWorkers:
    """Worker processes, each owning a group of vehicle steps; use as a context manager.

    Forked (the steps, the recording and `work` are inherited, nothing is pickled up front),
    so this needs a platform with fork; `available()` says whether it has one.
    """

    def __init__(self, groups: Sequence[Mapping[str, VehicleStep]], work: EpochWork, n_epochs: int) -> None:
        ctx = mp.get_context("fork")
        self._conns: list[Connection] = []
        self._procs: list[Any] = []
        for steps in groups:
            parent, child = ctx.Pipe()
            p = ctx.Process(target=_serve, args=(child, steps, work, n_epochs), daemon=True)
            p.start()
            child.close()
            self._conns.append(parent)
            self._procs.append(p)

    @staticmethod
    def available() -> bool:
        return "fork" in mp.get_all_start_methods()

    def submit(self, k: int, previous: SolutionMessage | None) -> None:
        """Start epoch `k` in every worker (returns at once)."""
        req: Request = (k, previous)
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
