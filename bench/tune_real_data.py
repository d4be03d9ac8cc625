"""The real-data check of factor-graph settings: `non-cp` variants on ../shared/data/real.

    .venv/bin/python bench/tune_real_data.py --out docs/tuning-real.md
    .venv/bin/python bench/tune_real_data.py --variants default,pr-sigma-x2

The simulator shares its error models with the library, so a setting that wins on the training
seeds (bench/tune_fgo.py) can win for the wrong reason. Before a setting becomes a default it must
not lose here: the static sets give errors against the surveyed point, the moving drive (no truth)
the divergence indicators of bench/real_data_regression.py and its errors against RTKLIB's RTK.
Variants are bench/tune_fgo.py's (each changes the current defaults in one respect); RTKLIB's code
row is not rerun (docs/results.md has it).
"""

from __future__ import annotations

import argparse
import datetime as dt
import sys
from pathlib import Path

import numpy as np
from real_data_regression import REAL, STATIC, set_sections
from tune_fgo import apply_variant

from coplane.evaluate.real_data import truth_of
from coplane.evaluate.runner import run_method
from coplane.geo import ecef_to_geodetic, enu_rotation
from coplane.messages import NodeMessage, SolutionMessage
from coplane.methods import MethodSpec, get_method
from coplane.recording.reader import open_recording

BASE = "non-cp"  # one receiver per set: the single-vehicle factor graph
SEP = "@"  # "non-cp@pr-sigma-x2": the method with a tune_fgo variant applied


def variant_method(name: str) -> MethodSpec:
    """`non-cp@variant` as a method spec; plain names as the registry has them."""
    base, _, variant = name.partition(SEP)
    spec = get_method(base)
    return apply_variant(spec, variant) if variant else spec


def static_velocity_errors(folder: str) -> np.ndarray:
    """Every node message's Doppler velocity of a static real set (standalone front end) in the
    local ENU frame, in epoch order: its error, the true velocity being zero (n, 3) m/s.
    bench/moving_car_rtk.py sets the moving car beside it."""
    rec = open_recording(REAL / folder)
    vid = rec.manifest.vehicles[0].id
    vel: list[tuple[float, float, float]] = []

    def keep(_sol: SolutionMessage, msgs: dict[str, NodeMessage]) -> None:
        m = msgs.get(vid)
        if m is not None and m.velocity is not None:
            vel.append(m.velocity.velocity_ecef_mps)

    run_method(rec, BASE, dgnss=False, vehicles=[vid], jobs=1, on_solution=keep)
    truth = next(iter(truth_of(rec, vid).values()))
    return np.asarray(vel, dtype=float).reshape(-1, 3) @ enu_rotation(*ecef_to_geodetic(truth)[:2]).T


def doppler_section() -> list[str]:
    """How good the front end's Doppler velocity really is: a static receiver's true velocity is
    zero, so every node message's velocity is its error. The Doppler links' sigma_v is chosen
    against this (docs/fgo.md, round of 2026-11-25), not against the simulator's Doppler."""
    rows = [
        "## Doppler velocity error of the static sets\n",
        "The node messages' Doppler velocity (standalone front end) in the local ENU frame against zero; "
        "`2-epoch mean` is what a Doppler link uses (the mean of both epochs' velocities).\n",
        "| set | epochs with velocity | RMS E / N / U (m/s) | 2-epoch mean RMS E / N / U (m/s) | max abs E / N / U (m/s) |",
        "|---|---|---|---|---|",
    ]
    for folder, _, _ in STATIC:
        e = static_velocity_errors(folder)
        mean2 = (e[1:] + e[:-1]) / 2.0

        def f(x: np.ndarray) -> str:
            return " / ".join(f"{v:.3f}" for v in x)

        rows.append(
            f"| `{folder}` | {len(e)} | {f(np.sqrt(np.mean(e**2, axis=0)))} "
            f"| {f(np.sqrt(np.mean(mean2**2, axis=0)))} | {f(np.abs(e).max(axis=0))} |"
        )
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--variants",
        default="default,sigma-v-0.3,sigma-v-0.2,sigma-v-0.05,pr-sigma-x2",
        help="comma-separated bench/tune_fgo.py variants",
    )
    ap.add_argument("--out", type=Path, default=None, help="also write the tables here")
    args = ap.parse_args()
    names = [f"{BASE}{SEP}{v}" if v != "default" else BASE for v in args.variants.split(",")]
    parts = [
        "# Tuning: the real-data check\n",
        f"Output of `.venv/bin/python bench/tune_real_data.py {' '.join(sys.argv[1:])}` ({dt.date.today()}): "
        f"`{BASE}` with each bench/tune_fgo.py variant (`{BASE}{SEP}<variant>`) on the real sets of "
        "docs/results.md, kinematic processing. A default chosen on the training seeds "
        '(docs/tuning.md) must not lose here. RTKLIB is not rerun, so the "common" columns are '
        "empty (docs/results.md has them); the moving drive has no truth, so it gets the "
        "divergence indicators of docs/results.md (largest 3-D step, largest height excursion) and "
        "the errors against RTKLIB's RTK where that gives a reference (since 2026-11-29; the "
        "tables made before have only the indicators).\n",
    ]
    parts += set_sections(names, 1, level="##", resolve=variant_method, rtklib=False)
    parts += doppler_section()
    print("\n".join(parts), flush=True)
    if args.out is not None:
        args.out.write_text("\n".join(parts) + "\n")


if __name__ == "__main__":
    main()
