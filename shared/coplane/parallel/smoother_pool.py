"""Clusters solved on several cores: each cluster's smoother lives in one of a few processes.

GTSAM's Python wrapper keeps the GIL while it optimises (docs/performance-scale.md, "Threads and
GTSAM"), so threads cannot solve two clusters at once, and GTSAM's own TBB threading works inside
one elimination, not across our independent clusters (and the PyPI wheel has no TBB). A
smoother's iSAM2 state cannot be moved cheaply either. So each smoother is pinned to a process for
its life: the estimator keeps the window and makes every graph's recipes, and a slot's epoch goes,
as those recipes (`coplane.fgo.recipes`: builders and plain arguments, far cheaper to pickle than
GTSAM's text serialisation of the factors) and its new values, to the process that holds the
slot's smoother, which builds the factors. A smoother rebuilt for a merged or split cluster is a
new slot and goes to the process whose solves would end first (the vehicles it holds times its
measured solve seconds per vehicle). The estimator's own process is
worker 0, so `SmootherPool(config, N)` uses N cores with N - 1 child processes.

The solution is the sequential one, bit for bit: a smoother's results depend only on its own
inputs, which the same recipes and values reach in every process (pickling keeps doubles exact,
and the builders are deterministic; tests/parallel/test_smoother_pool.py). A dead child costs its
clusters a rebuild on the others, never the estimator.

Requests and replies are pickled over the anonymous `multiprocessing` pipes between the server and
the children it started (no address anyone else can connect to), so nothing from the bus or a
file is ever unpickled here.

Written here because nothing fits: `multiprocessing.Pool` and `concurrent.futures` hand a task to
any free worker, while a smoother must stay where its state is.
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing as mp
import pickle
import time
from collections.abc import Sequence
from multiprocessing.connection import Connection
from typing import Any

import gtsam
import numpy as np

from coplane.fgo.config import FgoConfig
from coplane.fgo.keys import is_position_key
from coplane.fgo.recipes import from_wire, to_wire
from coplane.fgo.smoother import LocalSmoothers, SmootherCluster, SmootherTask
from coplane.fgo.solve import Smoothers
from coplane.fgo.window import ClusterResult, graph_recipes

log = logging.getLogger("coplane.parallel")
CLOSE_TIMEOUT_S = 5.0
COST_SMOOTHING = 0.2  # weight of the newest epoch in each worker's running cost per vehicle

Packed = tuple[list[int], list[list[float]], list[int], list[float]]


def smoothers_for(config: FgoConfig | None, workers: int) -> Smoothers | None:
    """A pool of `workers` processes for an estimator with `config`, or None where one process is
    all there is to use: one worker, a filter (no factor graph), or `lm-window` (no smoothers)."""
    if workers < 1:
        raise ValueError(f"cluster workers must be at least 1, got {workers}")
    if workers == 1 or config is None or config.solver == "lm-window":
        return None
    return SmootherPool(config, workers)


def pack_values(values: gtsam.Values) -> Packed:
    """Positions and clocks as plain lists: GTSAM serialises Point3 values but not doubles."""
    pk: list[int] = []
    pos: list[list[float]] = []
    ck: list[int] = []
    clk: list[float] = []
    for key in values.keys():  # noqa: SIM118 (gtsam.Values has keys(), no iteration)
        if is_position_key(key):
            pk.append(key)
            pos.append([float(x) for x in values.atPoint3(key)])
        else:
            ck.append(key)
            clk.append(float(values.atDouble(key)))
    return pk, pos, ck, clk


def unpack_values(packed: Packed) -> gtsam.Values:
    pk, pos, ck, clk = packed
    out = gtsam.Values()
    for key, p in zip(pk, pos, strict=True):
        out.insertPoint3(key, np.asarray(p, dtype=float))
    for key, c in zip(ck, clk, strict=True):
        out.insert(key, c=c)
    return out


_ERRORS: dict[str, type[RuntimeError]] = {}


def remote_error(name: str, message: str) -> RuntimeError:
    """The worker's exception as one of the same class name, so a skipped reason reads the same."""
    cls = _ERRORS.setdefault(name, type(name, (RuntimeError,), {}))
    return cls(message)


def _serve(conn: Connection, cfg: FgoConfig) -> None:
    """A child process: solve the tasks of each request on the smoothers it holds, until told to stop."""
    smoothers: dict[int, SmootherCluster] = {}
    while True:
        try:
            raw = conn.recv_bytes()
        except EOFError:  # the estimator's process is gone
            return
        t0 = time.perf_counter()
        request = pickle.loads(raw)
        if request is None:
            return
        drops, tasks = request
        for slot in drops:
            smoothers.pop(slot, None)
        replies: list[tuple[Any, ...]] = []
        for slot, create, vehicles, recipes, initial, stamps, cov_keys, keys, pos_keys, converge in tasks:
            if create:
                smoothers[slot] = SmootherCluster(cfg, vehicles)
            try:
                res = smoothers[slot].solve_graph(
                    from_wire(recipes), unpack_values(initial), stamps, cov_keys, keys, pos_keys, converge
                )
                replies.append(
                    ("ok", pack_values(res.values), res.covariances, res.iterations, res.error_after)
                )
            except Exception as exc:
                smoothers.pop(slot, None)
                replies.append(("error", type(exc).__name__, str(exc)))
        conn.send((time.perf_counter() - t0, replies))


class SmootherPool:
    """The smoothers of every slot, spread over this process and `workers - 1` child processes."""

    def __init__(self, cfg: FgoConfig, workers: int) -> None:
        if workers < 2:
            raise ValueError(f"a pool needs at least 2 workers, got {workers}")
        self.cfg = cfg
        self._local = LocalSmoothers(cfg)
        ctx = mp.get_context("spawn")  # fork would copy a server's Zenoh threads in a broken state
        self._conns: list[Connection | None] = [None]  # worker 0 is this process
        self._procs: list[Any] = [None]
        for _ in range(workers - 1):
            parent, child = ctx.Pipe()
            proc = ctx.Process(target=_serve, args=(child, cfg), daemon=True, name="coplane-smoothers")
            proc.start()
            child.close()
            self._conns.append(parent)
            self._procs.append(proc)
        self._worker_of: dict[int, int] = {}  # slot -> worker
        # seconds per vehicle of a task's solve, per worker, as measured. Shipping is left out: it
        # is paid before and after the solves whoever takes the next smoother, so the epoch ends
        # soonest when the solves themselves end together
        self._cost = [1e-3] * workers  # a first guess, the same for all: the first epochs replace it
        self._size: dict[int, int] = {}  # slot -> its vehicles
        self._drops: list[list[int]] = [[] for _ in range(workers)]
        self.dead: set[int] = set()
        self.tasks = [0] * workers  # tasks each worker was given: how the load spread
        self.shipping_s = 0.0  # this process's seconds spent packing and unpacking children's tasks
        # where a round's time goes, for benchmarks: each worker's seconds solving its tasks, and
        # this process's seconds waiting for children's replies after its own solves (idle)
        self.busy_s = [0.0] * workers
        self.wait_s = 0.0

    @property
    def workers(self) -> int:
        return len(self._conns)

    def status(self) -> tuple[int, int]:
        """(processes, how many of them died)."""
        return self.workers, len(self.dead)

    def _place(self, task: SmootherTask) -> int | None:
        """The worker of the task's slot: where its smoother is, or the least loaded for a new one;
        None for a smoother that was lost with its worker."""
        if task.create:  # a new slot id: never one the pool holds
            load = [0] * self.workers  # vehicles each worker's smoothers hold
            for slot, held_by in self._worker_of.items():
                load[held_by] += self._size[slot]
            alive = [w for w in range(self.workers) if w not in self.dead]
            n = len(task.vehicles)
            w = min(alive, key=lambda i: ((load[i] + n) * self._cost[i], i))
            self._worker_of[task.slot] = w
            self._size[task.slot] = n
            return w
        return self._worker_of.get(task.slot)

    def _forget(self, slot: int) -> None:
        w = self._worker_of.pop(slot)
        del self._size[slot]
        if w > 0 and w not in self.dead:
            self._drops[w].append(slot)

    def run(self, tasks: Sequence[SmootherTask]) -> list[ClusterResult | Exception]:
        """Each task's result or exception, in order; the workers solve their share at once."""
        out: list[ClusterResult | Exception | None] = [None] * len(tasks)
        by_worker: dict[int, list[int]] = {}
        for i, task in enumerate(tasks):
            w = self._place(task)
            if w is None:
                out[i] = RuntimeError(f"smoother {task.slot} was lost with its worker")
                continue
            by_worker.setdefault(w, []).append(i)
            self.tasks[w] += 1
        sent: dict[int, float] = {}  # worker -> seconds this process spent shipping its tasks
        for w, idx in sorted(by_worker.items()):
            if w == 0:
                continue
            if w in self.dead:
                for i in idx:
                    out[i] = RuntimeError(f"smoother worker {w} is gone")
                continue
            t0 = time.perf_counter()
            wire = [_wire(tasks[i]) for i in idx]
            try:
                self._send(w, (self._drops[w], wire))
                self._drops[w] = []
                sent[w] = time.perf_counter() - t0
            except (OSError, EOFError) as exc:
                self._lost(w, idx, out, exc)
        t0 = time.perf_counter()
        for i in by_worker.get(0, []):
            out[i] = self._local.run_one(tasks[i])
        if by_worker.get(0):
            self._measured(0, time.perf_counter() - t0, [tasks[i] for i in by_worker[0]])
        for w, shipping_s in sent.items():
            idx = by_worker[w]
            t0 = time.perf_counter()
            try:
                raw = self._recv_bytes(w)
            except (OSError, EOFError) as exc:
                self._lost(w, idx, out, exc)
                continue
            finally:
                self.wait_s += time.perf_counter() - t0
            t0 = time.perf_counter()
            busy_s, replies = pickle.loads(raw)
            for i, reply in zip(idx, replies, strict=True):
                out[i] = _result(reply)
            unpack_s = time.perf_counter() - t0
            self._measured(w, busy_s, [tasks[i] for i in idx])
            self.shipping_s += shipping_s + unpack_s
        for i, res in enumerate(out):
            if isinstance(res, Exception) and tasks[i].slot in self._worker_of:
                self._forget(tasks[i].slot)  # the worker dropped a smoother that failed
        return [r if r is not None else RuntimeError("no reply") for r in out]

    def _measured(self, w: int, seconds: float, tasks: list[SmootherTask]) -> None:
        self.busy_s[w] += seconds
        vehicles = sum(len(t.vehicles) for t in tasks)
        if vehicles:
            a = COST_SMOOTHING
            self._cost[w] = (1 - a) * self._cost[w] + a * seconds / vehicles

    def wait_ready(self) -> None:
        """Block until every child has started (imported GTSAM): for benchmarks that time steps."""
        for w in range(1, self.workers):
            if w in self.dead:
                continue
            try:
                self._send(w, (self._drops[w], []))
                self._drops[w] = []
                self._recv_bytes(w)
            except (OSError, EOFError) as exc:
                self._lost(w, [], [], exc)

    def _send(self, w: int, request: Any) -> None:
        conn = self._conns[w]
        assert conn is not None
        conn.send(request)

    def _recv_bytes(self, w: int) -> bytes:
        conn = self._conns[w]
        assert conn is not None
        return conn.recv_bytes()

    def _lost(self, w: int, idx: list[int], out: list[Any], exc: BaseException) -> None:
        """A child died: its tasks fail (their clusters are rebuilt elsewhere), it gets no more."""
        if w not in self.dead:
            log.warning(
                "cluster worker lost; its clusters are rebuilt in the processes left",
                extra={"worker": w, "error": type(exc).__name__, "left": self.workers - len(self.dead) - 1},
            )
        self.dead.add(w)
        for i in idx:
            out[i] = RuntimeError(f"smoother worker {w} is gone: {type(exc).__name__}")
        for slot in [s for s, ww in self._worker_of.items() if ww == w]:
            self._forget(slot)

    def keep(self, slots: set[int]) -> None:
        """Forget the smoothers of every other slot (the children drop theirs with the next request)."""
        for slot in [s for s in self._worker_of if s not in slots]:
            self._forget(slot)
        self._local.keep({s for s, w in self._worker_of.items() if w == 0})

    def close(self) -> None:
        """Stop the children; a child that does not stop in time is terminated."""
        for w, conn in enumerate(self._conns):
            if conn is None:
                continue
            with contextlib.suppress(OSError, EOFError):
                conn.send(None)
            proc = self._procs[w]
            proc.join(CLOSE_TIMEOUT_S)
            if proc.is_alive():
                proc.terminate()
                proc.join(CLOSE_TIMEOUT_S)
            conn.close()
        self._conns = [None]
        self._procs = [None]
        self._local.close()


def _wire(t: SmootherTask) -> tuple[Any, ...]:
    """A task as a child receives it: its graph's recipes, the new values as plain lists."""
    recipes = to_wire(graph_recipes(t.blocks, t.ranges, t.priors, t.oldest_step))
    pos_keys = [b.pos_key for b in t.blocks]
    return (
        t.slot,
        t.create,
        t.vehicles,
        recipes,
        pack_values(t.initial),
        t.timestamps,
        t.cov_keys,
        t.estimate_keys,
        pos_keys,
        t.converge,
    )


def _result(reply: tuple[Any, ...]) -> ClusterResult | Exception:
    if reply[0] == "ok":
        _, values, covs, iterations, error = reply
        return ClusterResult(unpack_values(values), covs, iterations, float("nan"), error)
    return remote_error(reply[1], reply[2])
