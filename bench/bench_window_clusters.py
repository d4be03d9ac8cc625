"""The estimator's window-cluster bound (`FgoConfig.window_cluster_max`, issue 16): cost and accuracy.

    .venv/bin/python bench/bench_window_clusters.py [--vehicles 256] [--duration 30]
        [--seeds 11,12,13] [--training 11] [--caps 0,16,32,48] [--out docs/performance-scale.md]

For each seed: a simulated city (`coplane simulate --scenario city`), replayed in process with
method pc while the estimator's epoch inputs are recorded (with no window bound, so every bound
below gets the same inputs); then the fusion estimator alone over those inputs once per bound:
its CPU seconds per vehicle-epoch (`FusionEstimator.step` only: what a fusion server's solve
costs), the ratio to no bound in the same run, the horizontal and vertical RMSE against the
simulator's truth, the ranges the bound left out, and the smoothers rebuilt from the window (a
cluster that merged or split): how many, their share of the estimator's CPU and their sizes. The default was chosen on the `--training`
seeds; the other seeds are the report.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from docblock import write_block  # bench/ is the script's directory, first on sys.path

ROOT = Path(__file__).resolve().parents[1]
MARK = "bench_window_clusters"


def simulate_city(out: Path, vehicles: int, duration: float, seed: int) -> None:
    """`coplane simulate --scenario city` into `out` (the cities of this and the estimator's
    other benchmarks: bench_fusion_breakdown.py, bench_fusion_variants.py)."""
    subprocess.run(
        [sys.executable, "-m", "coplane.cli", "simulate", "--scenario", "city", "--vehicles", str(vehicles),
         "--duration", str(duration), "--seed", str(seed), "--out", str(out)],
        check=True, capture_output=True, cwd=ROOT,
    )  # fmt: skip


def record_inputs(rec_dir: Path) -> tuple[Any, list[Any]]:
    """The pc estimator's config and every epoch input of an in-process replay, no window bound."""
    import coplane.fgo.window as window
    from coplane.evaluate.runner import run_method
    from coplane.fgo.engine import FusionEstimator
    from coplane.recording.reader import open_recording

    inputs: list[Any] = []
    configs: list[Any] = []
    step, bounded = FusionEstimator.step, window.Window.bounded

    def recording_step(self: FusionEstimator, epoch: Any) -> Any:
        inputs.append(epoch)
        configs.append(self.config)
        return step(self, epoch)

    FusionEstimator.step = recording_step  # type: ignore[method-assign]
    window.Window.bounded = lambda self, ranges, new, cap: list(ranges)  # type: ignore[method-assign]
    try:
        run_method(open_recording(rec_dir), "pc", jobs=1)
    finally:
        FusionEstimator.step = step  # type: ignore[method-assign]
        window.Window.bounded = bounded  # type: ignore[method-assign]
    return configs[0], inputs


def replay(rec_dir: Path, config: Any, inputs: list[Any], cap: int) -> dict[str, Any]:
    """The estimator alone over `inputs` with window_cluster_max = cap: cost and errors."""
    import coplane.fgo.smoother as smoother
    from coplane.fgo.engine import FusionEstimator
    from coplane.geo import up_vector
    from coplane.recording.reader import open_recording

    rec = open_recording(rec_dir)
    truth = {v.id: rec.truth_at(v.id) for v in rec.manifest.vehicles}
    est = FusionEstimator(dataclasses.replace(config, window_cluster_max=cap))
    rebuilt: list[int] = []  # vehicles of each smoother built from the window (priors given)
    rebuild_cpu = [0.0]
    update = smoother.SmootherCluster.update

    def counted(self: Any, blocks: Any, ranges: Any, priors: Any, *a: Any, **kw: Any) -> Any:
        c0 = time.process_time()
        try:
            return update(self, blocks, ranges, priors, *a, **kw)
        finally:
            if priors:
                rebuilt.append(len(self.vehicles))
                rebuild_cpu[0] += time.process_time() - c0

    smoother.SmootherCluster.update = counted  # type: ignore[method-assign]
    cpu, n, dropped, h, v = 0.0, 0, 0, [], []
    digest = hashlib.sha256()
    for epoch in inputs:
        c0 = time.process_time()
        sol = est.step(epoch)
        cpu += time.process_time() - c0
        n += len(epoch.vehicles)
        dropped += sol.rejected.get("range_cluster_bound", 0)
        for vid, e in sorted(sol.estimates.items()):
            digest.update(vid.encode() + np.asarray(e.position_m, dtype=float).tobytes())
            tr = truth[vid].get(sol.time)
            if tr is None:
                continue
            d = np.asarray(e.position_m) - np.asarray(tr)
            up = up_vector(np.asarray(tr))
            dv = float(d @ up)
            v.append(dv)
            h.append(float(np.linalg.norm(d - dv * up)))
    smoother.SmootherCluster.update = update  # type: ignore[method-assign]
    rms = lambda x: float(np.sqrt(np.mean(np.square(x))))  # noqa: E731
    return {
        "ms": 1e3 * cpu / n,
        "h": rms(h),
        "v": rms(v),
        "dropped": dropped,
        "rebuilds": len(rebuilt),
        "rebuild_share": rebuild_cpu[0] / cpu,
        "rebuilt_median": float(np.median(rebuilt)) if rebuilt else 0.0,
        "rebuilt_max": max(rebuilt, default=0),
        "digest": digest.hexdigest(),  # every position, bit for bit: same run, same numbers?
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--vehicles", type=int, default=256)
    ap.add_argument("--duration", type=float, default=30.0)
    ap.add_argument("--seeds", default="11,12,13")
    ap.add_argument("--training", default="11", help="seeds the default was chosen on")
    ap.add_argument("--caps", default="0,16,32,48")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    from docblock import on_service_allocator

    malloc = on_service_allocator()  # the services' allocator: their CPU figures
    seeds = [int(s) for s in args.seeds.split(",")]
    training = {int(s) for s in args.training.split(",")}
    caps = [int(c) for c in args.caps.split(",")]
    rows = [
        "| city seed | role | window cluster bound | fusion CPU ms / vehicle-epoch | vs no bound | "
        "H RMSE (m) | V RMSE (m) | ranges left out | smoother rebuilds | their share of the CPU | "
        "rebuilt cluster vehicles median / max |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    with tempfile.TemporaryDirectory(prefix="coplane-wclusters-") as tmp:
        for seed in seeds:
            rec_dir = Path(tmp) / f"city-{seed}"
            simulate_city(rec_dir, args.vehicles, args.duration, seed)
            config, inputs = record_inputs(rec_dir)
            base: float | None = None
            for cap in caps:
                r = replay(rec_dir, config, inputs, cap)
                base = r["ms"] if cap == 0 else base
                ratio = f"{r['ms'] / base:.2f}" if base else "-"
                role = "training" if seed in training else "report"
                rows.append(
                    f"| {seed} | {role} | {cap or 'none'} | {r['ms']:.2f} | {ratio} | {r['h']:.3f} | "
                    f"{r['v']:.3f} | {r['dropped']} | {r['rebuilds']} | {100 * r['rebuild_share']:.0f} % | "
                    f"{r['rebuilt_median']:.0f} / {r['rebuilt_max']} |"
                )
                print(rows[-1], flush=True)
    head = (
        f"machine: {platform.machine()}, 2 CPUs, Python {platform.python_version()}, malloc {malloc}; cities of "
        f"{args.vehicles} vehicles x {args.duration:.0f} s, method pc, the estimator alone on recorded inputs"
    )
    table = head + "\n\n" + "\n".join(rows)
    print(table)
    if args.out is not None:
        cmd = (
            f"python bench/bench_window_clusters.py --vehicles {args.vehicles} --duration {args.duration:.0f} "
            f"--seeds {args.seeds} --training {args.training} --caps {args.caps} --out {args.out}"
        )
        write_block(args.out, MARK, cmd, table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
