"""Where a fusion server's estimator spends its CPU on a city (issue 16: the 1.0 ms target).

    .venv/bin/python bench/bench_fusion_breakdown.py [--vehicles 256] [--duration 20] [--seed 11]
        [--warmup 10] [--block NAME] [--out docs/performance-scale.md]

A simulated city (`coplane simulate --scenario city`) is replayed in process with method pc while
the estimator's epoch inputs are recorded; then the estimator alone (`FusionEstimator.step`, what
a fusion server's solve costs) runs over them with its defaults, and the CPU of its parts is
summed after the first `--warmup` epochs (the window and the clusters fill up first; the cost
per vehicle grows until then). Parts, timed by wrapping them: the input validation, each
vehicle's preparation (FDE screening, factor blocks), the iSAM2 smoother updates that add an
epoch's factors (or build a smoother from the window), apart for the one per cycle that
marginalises and relinearises (`FgoConfig.isam2_cycle_updates`) and the others, the updates
without new factors (the convergence loop of a new or rebuilt smoother), the marginal
covariances, and the rest of the step (window bookkeeping, clustering, estimates). CPU is
`time.process_time`: compare the rows of one run, as the host's speed varies between runs.
A second table counts the smoother tasks: an epoch fed to a cluster's smoother, or a smoother
built or rebuilt from the window (a cluster that merged, split or took a vehicle with earlier
states), with their sizes, GTSAM updates and CPU: a denser city rebuilds more.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from collections import defaultdict
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))
MARK = "bench_fusion_breakdown"


@contextmanager
def timed(owner: Any, name: str, part: Callable[..., str], cpu: dict[str, float]) -> Iterator[None]:
    """Wrap `owner.name` so that its CPU is added to cpu[part(*args)] (nested parts included)."""
    original = getattr(owner, name)

    def wrapper(*args: Any, **kw: Any) -> Any:
        c0 = time.process_time()
        try:
            return original(*args, **kw)
        finally:
            cpu[part(*args)] += time.process_time() - c0

    setattr(owner, name, wrapper)
    try:
        yield
    finally:
        setattr(owner, name, original)


def breakdown(inputs: list[Any], config: Any, warmup: int) -> tuple[dict[str, float], int, dict[str, float]]:
    """CPU seconds per part of the estimator over `inputs[warmup:]`, the vehicle-epochs, and the
    smoother tasks' counts and CPU (`task_rows`)."""
    import gtsam

    import coplane.fgo.engine as engine
    import coplane.fgo.smoother as smoother
    from coplane.fgo.engine import FusionEstimator

    est = FusionEstimator(config)
    for epoch in inputs[:warmup]:
        est.step(epoch)
    cpu: dict[str, float] = defaultdict(float)
    parts = [
        (engine, "validate_epoch", lambda *a: "input validation"),
        (engine, "prepare_vehicle", lambda *a: "vehicle preparation (FDE, factor blocks)"),
        (
            gtsam.IncrementalFixedLagSmoother,
            "update",
            # the lag is the config's on the update that marginalises and relinearises, and
            # stretched on the others of its cycle (`SmootherCluster._update`)
            lambda self, *a: (
                "smoother updates with an epoch's factors, marginalising and relinearising"
                if self.smootherLag() == config.lag
                else "smoother updates with an epoch's factors, in between"
            ),
        ),
        # the convergence loop of a new smoother or track, straight to iSAM2
        (gtsam.ISAM2, "update", lambda *a: "smoother updates without new factors"),
        (smoother, "marginal_covariances", lambda *a: "marginal covariances"),
    ]
    n = 0
    tasks: dict[str, float] = defaultdict(float)
    run_one = smoother.LocalSmoothers.run_one

    def counted(self: Any, task: Any) -> Any:
        """What each smoother task was: the new epoch fed to a smoother, or a smoother (re)built
        from the window, as a cluster merged, split or took a vehicle with earlier states."""
        kind = "built" if task.create else "fed"
        c0 = time.process_time()
        res = run_one(self, task)
        tasks[f"{kind} cpu"] += time.process_time() - c0
        tasks[f"{kind} tasks"] += 1
        tasks[f"{kind} vehicles"] += len(task.vehicles)
        tasks[f"{kind} updates"] += getattr(res, "iterations", 0)
        return res

    with ExitStack() as stack:
        smoother.LocalSmoothers.run_one = counted
        stack.callback(setattr, smoother.LocalSmoothers, "run_one", run_one)
        for part in parts:
            stack.enter_context(timed(*part, cpu))
        c0 = time.process_time()
        for epoch in inputs[warmup:]:
            est.step(epoch)
            n += len(epoch.vehicles)
        total = time.process_time() - c0
    cpu["rest of the step (window, clusters, estimates)"] = total - sum(cpu.values())
    cpu["whole step"] = total
    return dict(cpu), n, dict(tasks)


def task_rows(tasks: dict[str, float], n: int, epochs: int) -> list[str]:
    """The smoother tasks of the timed epochs: how many, how big, how many GTSAM updates each, and
    their CPU (the same CPU as the parts above, split another way)."""
    rows = [
        "| smoother tasks | per epoch | vehicles each (mean) | GTSAM updates each (mean) | CPU ms / vehicle-epoch |",
        "|---|---|---|---|---|",
    ]
    for kind, what in (("fed", "fed the new epoch"), ("built", "built or rebuilt from the window")):
        k = max(tasks.get(f"{kind} tasks", 0.0), 1.0)
        rows.append(
            f"| {what} | {tasks.get(f'{kind} tasks', 0.0) / epochs:.1f} | {tasks.get(f'{kind} vehicles', 0.0) / k:.1f} "
            f"| {tasks.get(f'{kind} updates', 0.0) / k:.1f} | {1e3 * tasks.get(f'{kind} cpu', 0.0) / n:.2f} |"
        )
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--vehicles", type=int, default=256)
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--warmup", type=int, default=10)
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--block", default=MARK, help="the docs block to write (one per city size)")
    args = ap.parse_args()
    import bench_window_clusters as recorder  # the same recorded inputs as the window-bound table
    from docblock import machine, on_service_allocator, publish

    malloc = on_service_allocator()  # the services' allocator: their CPU figures

    with tempfile.TemporaryDirectory(prefix="coplane-breakdown-") as tmp:
        rec = Path(tmp) / "city"
        recorder.simulate_city(rec, args.vehicles, args.duration, args.seed)
        config, inputs = recorder.record_inputs(rec)  # pc's estimator config, defaults
    cpu, n, tasks = breakdown(inputs, config, args.warmup)
    total = cpu["whole step"]
    rows = ["| part | CPU ms / vehicle-epoch | share |", "|---|---|---|"]
    for part, sec in sorted(cpu.items(), key=lambda kv: -kv[1]):
        if part != "whole step":
            rows.append(f"| {part} | {1e3 * sec / n:.2f} | {100 * sec / total:.0f} % |")
    rows.append(f"| **whole step** | **{1e3 * total / n:.2f}** | 100 % |")
    rows += ["", *task_rows(tasks, n, len(inputs) - args.warmup)]
    head = (
        f"machine: {machine(cpus=False)}, malloc {malloc}; city of {args.vehicles} vehicles x "
        f"{args.duration:.0f} s (seed {args.seed}), method pc, the estimator alone on recorded inputs, "
        f"epochs after the first {args.warmup}: {n} vehicle-epochs"
    )
    cmd = (
        f"python bench/bench_fusion_breakdown.py --vehicles {args.vehicles} --duration {args.duration:.0f} "
        f"--seed {args.seed} --warmup {args.warmup}"
        + (f" --block {args.block}" if args.block != MARK else "")
        + f" --out {args.out}"
    )
    publish(args.out, args.block, cmd, head, rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
