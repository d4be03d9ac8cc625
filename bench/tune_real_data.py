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

from real_data_regression import set_sections
from tune_fgo import VARIANTS

from coplane.methods import MethodSpec, get_method

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
    parts = [
        "# Tuning: the real-data check\n",
        f"Output of `.venv/bin/python bench/tune_real_data.py --out docs/tuning-real.md` ({dt.date.today()}): "
        f"`{BASE}` with each bench/tune_fgo.py variant (`{BASE}{SEP}<variant>`) on the real sets of "
        "docs/results.md, kinematic processing. A default chosen on the training seeds "
        '(docs/tuning.md) must not lose here. RTKLIB is not rerun, so the "common" columns are '
        "empty (docs/results.md has them); the moving drive has no truth, so its columns are the "
        "divergence indicators of docs/results.md (largest 3-D step, largest height excursion).\n",
    ]
    parts += set_sections(names, 1, level="##", resolve=variant_method, rtklib=False)
    print("\n".join(parts), flush=True)
    if args.out is not None:
        args.out.write_text("\n".join(parts) + "\n")


if __name__ == "__main__":
    main()
