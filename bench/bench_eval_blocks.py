"""Where one method's `coplane eval` time goes: CPU seconds per block, everything in one process.

Wraps the per-vehicle and fusion functions with `time.process_time` (a few thousand calls, so the
wrappers cost little, unlike cProfile, which inflates small Python calls several times), runs the
method once to warm up and once measured, and prints a Markdown table for docs/performance.md.
Runs on older commits too (no `jobs` argument there), which is how a before/after is measured:

    .venv/bin/python bench/bench_eval_blocks.py pc
"""

from __future__ import annotations

import argparse
import collections
import inspect
import time
from collections.abc import Callable
from typing import Any

import coplane.evaluate.runner as runner
import coplane.gnss.epoch_solver as epoch_solver
import coplane.steps as steps
from coplane.recording.reader import open_recording
from coplane.sim.generate import bundled_default_path

CPU: collections.Counter[str] = collections.Counter()

# (owner, attribute, label); the front end's parts are wrapped where epoch_solver calls them
BLOCKS: list[tuple[Any, str, str]] = [
    (epoch_solver, "prepare_epoch", "satellite states (prepare_epoch, vehicles and base)"),
    (epoch_solver, "solve_spp", "SPP with FDE"),
    (epoch_solver, "solve_doppler_velocity", "Doppler velocity"),
    (steps.VehicleStep, "_satellites", "node message satellites"),
    (steps.VehicleStep, "_plane", "plane fit (_plane)"),
    (steps.VehicleStep, "ingest", "plane history (ingest)"),
    (steps.FusionStep, "solve", "fusion step"),
]


def _timed(f: Callable[..., Any], label: str) -> Callable[..., Any]:
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        t = time.process_time()
        try:
            return f(*args, **kwargs)
        finally:
            CPU[label] += time.process_time() - t

    return wrapper


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("method", nargs="?", default="pc")
    args = ap.parse_args()
    for owner, name, label in BLOCKS:
        setattr(owner, name, _timed(getattr(owner, name), label))
    rec = open_recording(bundled_default_path())
    kwargs = {"jobs": 1} if "jobs" in inspect.signature(runner.run_method).parameters else {}
    runner.run_method(rec, args.method, **kwargs)
    CPU.clear()
    t = time.process_time()
    runner.run_method(rec, args.method, **kwargs)
    total = time.process_time() - t
    print(f"| block ({args.method}, one process) | CPU s |\n|---|---|")
    for _, _, label in BLOCKS:
        print(f"| {label} | {CPU[label]:.2f} |")
    print(f"| whole run | {total:.2f} |")


if __name__ == "__main__":
    main()
