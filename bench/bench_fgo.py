"""Per-epoch cost of the fusion estimator for 4..256 vehicles, each solver, on the synthetic fleet.

The fleet drives in groups of 8 (two lanes, ~25 m rows) on their own tilted roads kilometres
apart; UWB ranges between vehicles within 100 m (so each group is one cluster); planes and ranges on
(method "pc"); 14 satellites per vehicle, one biased NLOS satellite each. The time is the whole
`FusionEstimator.step` (validation, factor building, clustering, solve, covariances), i.e. what a
fusion server spends per epoch. The first `window_epochs` epochs (window filling up) are excluded.

    .venv/bin/python bench/bench_fgo.py                       # prints the Markdown table
    .venv/bin/python bench/bench_fgo.py --out docs/performance-fgo.md
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import importlib.metadata
import math
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "support"))

from fgo_synthetic import error_stats, make_fleet

from coplane.fgo.config import SOLVERS
from coplane.fgo.engine import FusionEstimator
from coplane.methods import get_method


def _cpu() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown CPU"


def bench_one(n: int, solver: str, epochs: int, budget_s: float, split: bool = True) -> dict[str, object]:
    fleet = make_fleet(n, epochs, seed=1, nlos_per_vehicle=1, nlos_bias=(10.0, 30.0), max_range=100.0)
    cfg = dataclasses.replace(get_method("pc", solver=solver).fgo, split_clusters=split)  # type: ignore[arg-type]
    est = FusionEstimator(cfg)
    times: list[float] = []
    sols = []
    started = time.perf_counter()
    cut = False
    for k, epoch in enumerate(fleet.epochs):
        t0 = time.perf_counter()
        sol = est.step(epoch)
        dt = time.perf_counter() - t0
        sols.append(sol)
        if k >= cfg.window_epochs:
            times.append(dt)
        if time.perf_counter() - started > budget_s and k < len(fleet.epochs) - 1:
            cut = True
            break
    last = sols[-1]
    st = error_stats(fleet, sols, skip=cfg.window_epochs)
    return {
        "n": n,
        "solver": solver,
        "split": split,
        "epochs": len(times),
        "median_ms": 1e3 * float(np.median(times)) if times else math.nan,
        "p99_ms": 1e3 * float(np.percentile(times, 99)) if times else math.nan,
        "clusters": last.n_clusters,
        "factors": sum(last.factor_counts.values()),
        "h_rmse": st.h_rmse,
        "v_rmse": st.v_rmse,
        "cut": cut,
    }


def table(rows: list[dict[str, object]]) -> str:
    out = [
        "| vehicles | solver | clusters | factors in window | epochs timed | median ms/epoch | p99 ms/epoch | ms/vehicle (median) | h / v RMSE (m) |",
        "|---:|---|---:|---:|---:|---:|---:|---:|---|",
    ]
    for r in rows:
        solver = str(r["solver"]) + ("" if r["split"] else " (one graph, no cluster split)")
        note = " (budget hit: fewer epochs)" if r["cut"] else ""
        n = int(r["n"])  # type: ignore[call-overload]
        med = float(r["median_ms"])  # type: ignore[arg-type]
        out.append(
            f"| {n} | {solver} | {r['clusters']} | {r['factors']} | {r['epochs']}{note} | {med:.1f} | "
            f"{float(r['p99_ms']):.1f} | {med / n:.2f} | {float(r['h_rmse']):.2f} / {float(r['v_rmse']):.2f} |"  # type: ignore[arg-type]
        )
    return "\n".join(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    ap.add_argument("--sizes", default="4,16,64,256")
    ap.add_argument("--solvers", default=",".join(SOLVERS))
    ap.add_argument(
        "--epochs", type=int, default=30, help="epochs per run (the first window_epochs are not timed)"
    )
    ap.add_argument("--budget", type=float, default=90.0, help="seconds per run before it is cut short")
    ap.add_argument("--joint", default="64", help="sizes also run as one graph (split_clusters=False)")
    ap.add_argument("--out", type=Path, default=None, help="write the Markdown report here")
    args = ap.parse_args()
    load0 = os.getloadavg()[0]
    sizes = [int(s) for s in args.sizes.split(",") if s]
    solvers = [s for s in args.solvers.split(",") if s]
    joint = {int(s) for s in args.joint.split(",") if s}
    rows = []
    for n in sizes:
        for solver in solvers:
            rows.append(bench_one(n, solver, args.epochs, args.budget))
            print(table(rows[-1:]).splitlines()[-1], flush=True)
            if n in joint:
                rows.append(bench_one(n, solver, args.epochs, args.budget, split=False))
                print(table(rows[-1:]).splitlines()[-1], flush=True)
    body = table(rows)
    header = (
        f"Measured {datetime.date.today().isoformat()} on {os.cpu_count()} cores ({_cpu()}), "
        f"Python {platform.python_version()}, GTSAM {importlib.metadata.version('gtsam')}, "
        f"`bench/bench_fgo.py --sizes {args.sizes} --epochs {args.epochs} --budget {args.budget:g}`; "
        f"load average before the run {load0:.1f} (a shared machine: other jobs compete). "
        f"With {args.epochs} epochs the p99 is about the maximum."
    )
    print()
    print(header)
    print(body)
    if args.out is not None:
        text = args.out.read_text() if args.out.exists() else ""
        marker_start, marker_end = "<!-- bench_fgo:start -->", "<!-- bench_fgo:end -->"
        block = f"{marker_start}\n{header}\n\n{body}\n{marker_end}"
        if marker_start in text and marker_end in text:
            pre = text.split(marker_start)[0]
            post = text.split(marker_end, 1)[1]
            text = pre + block + post
        else:
            text = (text.rstrip() + "\n\n" if text else "") + block + "\n"
        args.out.write_text(text)


if __name__ == "__main__":
    main()
