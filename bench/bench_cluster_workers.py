"""Clusters solved on several cores inside one fusion server (issue 16): speed against workers.

    .venv/bin/python bench/bench_cluster_workers.py [--vehicles 256] [--duration 20] [--seed 11]
        [--workers 1,2] [--repeats 3] [--block NAME] [--out docs/performance-scale.md]

A simulated city (`coplane simulate --scenario city`), the pc estimator's epoch inputs recorded
once (an in-process replay, as `bench_window_clusters.py` does); then the estimator alone over
them with its cluster smoothers on N processes (`coplane.parallel.SmootherPool`) for each N, `--repeats` times in turn so that every N
shares the host's drift. Wall time is `step` over every epoch (the pool's processes are started
and ready before it); CPU is this process's plus the children's (counted once they exit), and
shipping is what this process spent pickling the children's factor recipes and new values and
reading their results. Each row also says whether its positions and covariances equal the single
process's bit for bit. A second table splits the wall time of the runs on several processes
(`SmootherPool.busy_s`, `wait_s`, `shipping_s`): what the server's process spent solving, waiting
for its children and shipping, and the rest of its step.
"""

from __future__ import annotations

import argparse
import hashlib
import resource
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))
MARK = "bench_cluster_workers"


def run_once(config: Any, inputs: list[Any], workers: int) -> dict[str, Any]:
    """Wall and CPU seconds of the estimator over `inputs`, and a digest of its estimates."""
    import numpy as np

    from coplane.fgo.engine import FusionEstimator
    from coplane.parallel import SmootherPool, smoothers_for

    est = FusionEstimator(config, smoothers=smoothers_for(config, workers))
    pool = est._smoothers
    if isinstance(pool, SmootherPool):
        pool.wait_ready()
    child0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu0 = time.process_time()
    t0 = time.perf_counter()
    digest = hashlib.sha256()
    n = 0
    for epoch in inputs:
        sol = est.step(epoch)
        n += len(epoch.vehicles)
        for vid in sorted(sol.estimates):
            e = sol.estimates[vid]
            digest.update(vid.encode())
            digest.update(np.asarray(e.position_m, dtype=float).tobytes())
            digest.update(np.asarray(e.covariance_m2, dtype=float).tobytes())
    wall = time.perf_counter() - t0
    cpu = time.process_time() - cpu0
    tasks = list(pool.tasks) if isinstance(pool, SmootherPool) else [0]
    shipping = pool.shipping_s if isinstance(pool, SmootherPool) else 0.0
    busy = list(pool.busy_s) if isinstance(pool, SmootherPool) else [0.0]
    waiting = pool.wait_s if isinstance(pool, SmootherPool) else 0.0
    est.close()
    child1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu += (child1.ru_utime + child1.ru_stime) - (child0.ru_utime + child0.ru_stime)
    return {
        "wall": wall,
        "cpu": cpu,
        "n": n,
        "digest": digest.hexdigest(),
        "tasks": tasks,
        "shipping": shipping,
        "busy": busy,
        "waiting": waiting,
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--vehicles", type=int, default=256)
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--workers", default="1,2")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--block", default=MARK, help="the docs block to write (one per fleet size)")
    args = ap.parse_args()
    import bench_window_clusters as recorder
    from docblock import machine, on_service_allocator, publish

    malloc = on_service_allocator()  # the services' allocator: their CPU figures

    counts = [int(w) for w in args.workers.split(",")]
    with tempfile.TemporaryDirectory(prefix="coplane-workers-") as tmp:
        rec = Path(tmp) / "city"
        recorder.simulate_city(rec, args.vehicles, args.duration, args.seed)
        config, inputs = recorder.record_inputs(rec)  # pc's estimator config, defaults
    runs: dict[int, list[dict[str, Any]]] = {w: [] for w in counts}
    for r in range(args.repeats):
        for w in counts:
            runs[w].append(run_once(config, inputs, w))
            print(f"repeat {r + 1}: {w} workers {runs[w][-1]['wall']:.2f} s", flush=True)
    base = statistics.median(x["wall"] for x in runs[counts[0]])
    ref = runs[counts[0]][0]["digest"]
    rows = [
        "| workers (processes) | wall s (median) | solved vehicle-epochs/s | speed-up vs "
        f"{counts[0]} | CPU ms / vehicle-epoch, all processes | of which shipping in the server's process | "
        f"tasks per process | estimates equal to {counts[0]} worker's |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for w in counts:
        wall = statistics.median(x["wall"] for x in runs[w])
        n = runs[w][0]["n"]
        cpu = statistics.median(x["cpu"] for x in runs[w])
        ship = statistics.median(x["shipping"] for x in runs[w])
        same = all(x["digest"] == ref for x in runs[w])
        tasks = " / ".join(str(t) for t in runs[w][0]["tasks"])
        rows.append(
            f"| {w} | {wall:.2f} | {n / wall:.0f} | {base / wall:.2f} | {1e3 * cpu / n:.2f} | {1e3 * ship / n:.2f} | {tasks} | "
            f"{'yes' if same else 'NO'} |"
        )
    if any(w > 1 for w in counts):
        rows += [
            "",
            "Where a multi-process run's wall time goes (median of the runs; the server is worker 0, "
            "a child's solves include reading its requests): the server's own solves, its time waiting "
            "for the children after them, its shipping, and the rest of the step, which no child shares.",
            "",
            "| workers (processes) | wall s | server's solves s | children's solves s | server waiting s | "
            "server shipping s | rest of the step s |",
            "|---|---|---|---|---|---|---|",
        ]
        for w in (w for w in counts if w > 1):
            med = {k: statistics.median(x[k] for x in runs[w]) for k in ("wall", "waiting", "shipping")}
            own = statistics.median(x["busy"][0] for x in runs[w])
            children = [statistics.median(x["busy"][i] for x in runs[w]) for i in range(1, w)]
            rest = med["wall"] - own - med["waiting"] - med["shipping"]
            rows.append(
                f"| {w} | {med['wall']:.2f} | {own:.2f} | {' / '.join(f'{c:.2f}' for c in children)} | "
                f"{med['waiting']:.2f} | {med['shipping']:.2f} | {rest:.2f} |"
            )
    head = (
        f"machine: {machine()}, malloc {malloc}; "
        f"city of {args.vehicles} vehicles x {args.duration:.0f} s (seed {args.seed}), method pc, the "
        f"estimator alone on recorded inputs, {len(inputs)} epochs, median of {args.repeats} runs"
    )
    cmd = (
        f"python bench/bench_cluster_workers.py --vehicles {args.vehicles} --duration {args.duration:.0f} "
        f"--seed {args.seed} --workers {args.workers} --repeats {args.repeats}"
        + (f" --block {args.block}" if args.block != MARK else "")
        + f" --out {args.out}"
    )
    publish(args.out, args.block, cmd, head, rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
