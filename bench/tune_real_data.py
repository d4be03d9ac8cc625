"""The real-data check of factor-graph settings: `non-cp` variants on ../shared/data/real.

    .venv/bin/python bench/tune_real_data.py --out docs/tuning-real.md
    .venv/bin/python bench/tune_real_data.py --variants default,pr-sigma-x2

The simulator shares its error models with the library, so a setting that wins on the training
seeds (bench/tune_fgo.py) can win for the wrong reason. Before a setting becomes a default it must
not lose here: the static sets give errors against the surveyed point, the moving drive (no truth)
the divergence indicators of bench/real_data_regression.py. Variants are bench/tune_fgo.py's (each
changes the current defaults in one respect); RTKLIB is not rerun (docs/results.md has it).
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime as dt
from pathlib import Path

from real_data_regression import MOVING, REAL, STATIC, _mode
from tune_fgo import VARIANTS

import coplane.evaluate.real_data as real_data
from coplane.evaluate.real_data import (
    solve_receiver,
    static_accuracy,
    static_table,
    trajectory_checks,
    trajectory_table,
    truth_of,
)
from coplane.methods import MethodSpec, get_method
from coplane.recording.reader import open_recording

BASE = "non-cp"  # one receiver per set: the single-vehicle factor graph
SEP = "@"  # "non-cp@pr-sigma-x2": the method with a tune_fgo variant applied


def variant_method(name: str) -> MethodSpec:
    """`non-cp@variant` as a method spec; plain names as the registry has them."""
    base, _, variant = name.partition(SEP)
    spec = get_method(base)
    if not variant or spec.fgo is None:
        return spec
    return dataclasses.replace(spec, fgo=dataclasses.replace(spec.fgo, **VARIANTS[variant]))  # type: ignore[arg-type]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--variants",
        default="default,sigma-v-0.2,adaptive-sigma,pr-sigma-x2",
        help="comma-separated bench/tune_fgo.py variants",
    )
    ap.add_argument("--out", type=Path, default=None, help="also write the tables here")
    args = ap.parse_args()
    names = [f"{BASE}{SEP}{v}" if v != "default" else BASE for v in args.variants.split(",")]
    real_data.get_method = variant_method  # type: ignore[assignment]  # solve_receiver resolves names
    real_data.rtklib_unavailable = lambda: "not rerun here (docs/results.md)"  # type: ignore[assignment]
    parts = [
        "# Tuning: the real-data check\n",
        f"Output of `.venv/bin/python bench/tune_real_data.py --out docs/tuning-real.md` ({dt.date.today()}): "
        f"`{BASE}` with each bench/tune_fgo.py variant (`{BASE}{SEP}<variant>`) on the real sets of "
        "docs/results.md, kinematic processing. A default chosen on the training seeds "
        '(docs/tuning.md) must not lose here. RTKLIB is not rerun, so the "common" columns are '
        "empty (docs/results.md has them); the moving drive has no truth, so its columns are the "
        "divergence indicators of docs/results.md (largest 3-D step, largest height excursion).\n",
    ]
    for folder, what, modes in STATIC:
        rec = open_recording(REAL / folder)
        for dgnss in modes:
            sol = solve_receiver(rec, names, dgnss=dgnss, keep_going=True)
            parts.append(f"## `{folder}`: {_mode(sol.dgnss)}\n\n{what}; {sol.n_epochs} epochs.\n")
            parts.append(static_table(static_accuracy(sol, truth_of(rec, sol.vehicle))))
            print("\n".join(parts[-2:]), flush=True)
    for folder, what, modes in MOVING:
        rec = open_recording(REAL / folder)
        for dgnss in modes:
            sol = solve_receiver(rec, names, dgnss=dgnss, keep_going=True)
            parts.append(f"## `{folder}`: {_mode(sol.dgnss)}\n\n{what}; {sol.n_epochs} epochs.\n")
            parts.append(trajectory_table(trajectory_checks(sol)))
            print("\n".join(parts[-2:]), flush=True)
    if args.out is not None:
        args.out.write_text("\n".join(parts) + "\n")


if __name__ == "__main__":
    main()
