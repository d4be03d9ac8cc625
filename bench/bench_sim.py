"""Simulator generation time: `python bench/bench_sim.py [--quick]`.

Runs `run_simulation` (motion, canyon, errors, UWB) and `write_recording` (RINEX, CSV, TOML) for a
few fleet sizes and prints a Markdown table (pasted into docs/simulator.md). The targets: 256
vehicles x 60 s within a few minutes on the 2-core CI machine; the `city` load-generation scenario
(issue 16) with 1000 vehicles x 120 s well under 3 minutes and a few hundred MB.
"""

from __future__ import annotations

import argparse
import os
import platform
import resource
import tempfile
import time
from pathlib import Path

from coplane.sim import run_simulation, write_recording

CASES = [
    ("urban-loop", 4, 600.0),
    ("urban-loop", 64, 60.0),
    ("urban-loop", 256, 60.0),
    ("dense-urban", 256, 60.0),
    ("city", 1000, 120.0),
]


def _size_mb(root: Path) -> float:
    return sum(p.stat().st_size for p in root.rglob("*") if p.is_file()) / 1e6


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--quick", action="store_true", help="only the default case")
    args = ap.parse_args()
    cases = CASES[:1] if args.quick else CASES
    print(
        f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, Python {platform.python_version()}"
    )
    print()
    print(
        "| scenario | vehicles x s | simulate s | write s | total s | receiver-epochs/s | files MB | obs/veh-epoch |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for scenario, vehicles, duration in cases:
        with tempfile.TemporaryDirectory() as tmp:
            t0 = time.perf_counter()
            res = run_simulation(scenario, vehicles, duration, seed=0)
            t1 = time.perf_counter()
            out = write_recording(res, Path(tmp) / "rec")
            t2 = time.perf_counter()
            n_ep = len(res.times)
            n_obs = sum(len(e.sats) for eps in res.vehicle_obs.values() for e in eps)
            rx_epochs = (vehicles + 1) * n_ep
            print(
                f"| {scenario} | {vehicles} x {duration:.0f} | {t1 - t0:.1f} | {t2 - t1:.1f} | {t2 - t0:.1f} |"
                f" {rx_epochs / (t2 - t0):.0f} | {_size_mb(out):.1f} | {n_obs / (vehicles * n_ep):.1f} |"
            )
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print()
    print(f"peak RSS {peak:.0f} MB")


if __name__ == "__main__":
    main()
