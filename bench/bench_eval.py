"""`coplane eval` cost on the bundled recording: wall time per method and per-epoch solve time.

The target: the bundled 4-vehicle, 600-epoch recording evaluates in under 10 s per method
on this 2-core machine. Median of `--repeats` runs (recording already loaded, as in `coplane eval`
after the first method), with the default jobs (one process per core: vehicle workers + the
fusion step, evaluate.vehicle_workers) and with everything in one process (`--jobs 1`); then both
again with the GNSS front ends an earlier run computed (`FrontEndMemo`, what `coplane eval --jobs
1` does from its second method on), printed as a Markdown table for docs/performance.md.

    .venv/bin/python bench/bench_eval.py --repeats 3 [--out docs/performance.md]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from coplane.evaluate.front_ends import FrontEndMemo
from coplane.evaluate.runner import run_method
from coplane.evaluate.vehicle_workers import default_jobs
from coplane.recording.reader import open_recording
from coplane.sim.generate import bundled_default_path

METHODS = ["non-cp", "mci", "pc", "pc-no-ir", "pc-no-ir-no-fe", "pc-self"]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--methods", default=",".join(METHODS))
    ap.add_argument("--out", type=Path, default=None, help="rewrite the bench_eval block of this page")
    args = ap.parse_args()
    t0 = time.perf_counter()
    rec = open_recording(bundled_default_path())
    for v in rec.manifest.vehicles:
        rec.vehicle_epochs(v.id)
    _ = rec.nav, rec.base_epochs(), rec.uwb()
    load_s = time.perf_counter() - t0
    rows = []
    jobs = default_jobs(len(rec.manifest.vehicles))
    memo = FrontEndMemo()
    run_method(rec, "non-cp", jobs=1, front_ends=memo)  # the front ends, once (not timed)
    for m in args.methods.split(","):
        walls, walls_1, walls_m, walls_m1, solves = [], [], [], [], []
        for _ in range(args.repeats):
            run = run_method(rec, m)
            walls.append(run.wall_time_s)
            solves.extend(run.solve_times_s)
            walls_1.append(run_method(rec, m, jobs=1).wall_time_s)
            walls_m.append(run_method(rec, m, front_ends=memo).wall_time_s)
            walls_m1.append(run_method(rec, m, jobs=1, front_ends=memo).wall_time_s)
        s = np.array(solves) * 1000
        w, w1, wm, wm1 = (float(np.median(x)) for x in (walls, walls_1, walls_m, walls_m1))
        rows.append(
            f"| {m} | {run.n_epochs} | {w:.1f} | {min(walls):.1f} | {w1:.1f} | {w1 / w:.2f} | "
            f"{wm:.1f} | {wm1:.1f} | {wm1 / w:.2f} | "
            f"{np.median(s):.1f} | {np.percentile(s, 99):.1f} | {'yes' if w < 10 else 'no'} |"
        )
        print(rows[-1], flush=True)
    from docblock import machine, publish

    head = (
        f"machine: {machine()}; bundled recording, 4 vehicles x 600 epochs, DGNSS, the methods' defaults "
        f"(docs/fgo.md); loading the recording: {load_s:.1f} s (once). Wall time per method = every "
        "vehicle's SPP, Doppler, plane and node message plus the fusion solve, median of "
        f'{args.repeats} runs, with the default {jobs} jobs and with `--jobs 1`; "front ends known": '
        "the same with the GNSS front ends (SPP, Doppler) an earlier run computed (`FrontEndMemo`)."
    )
    table = (
        "| method | epochs | wall s (median) | wall s (min) | wall s, 1 job | 1 job / default | "
        "front ends known: wall s | front ends known: wall s, 1 job | that / default | "
        "solve ms/epoch (median) | solve ms p99 | < 10 s |\n"
        "|---|---|---|---|---|---|---|---|---|---|---|---|"
    )
    rows = table.split("\n") + rows
    cmd = f"python bench/bench_eval.py --repeats {args.repeats}" + (f" --out {args.out}" if args.out else "")
    publish(args.out, "bench_eval", cmd, head, rows)


if __name__ == "__main__":
    main()
