"""Where does one factor-graph variant win or lose against another? Per seed and per epoch, on the
TRAINING seeds only (the held-out ones must not be looked into; bench/tune_fgo.py).

    .venv/bin/python bench/variant_epochs.py --scenario dense-urban --variants default,height-links-doppler \
        --trace 203

Prints, for each training seed of the scenario, `pc`'s pooled H / V RMSE, H p99 and underpass
H / V RMSE under both variants (bench/tune_fgo.py VARIANTS), then for the `--trace` seed each
vehicle's H RMSE and the epochs where the second variant's horizontal error grew most over the
first's, with the environment and both variants' H and up errors. This is how docs/fgo.md found
why the road-height links cost dense-urban horizontally ("Road-height links, tried twice").
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np
from tune_fgo import apply_variant

from coplane.evaluate.benchmark import TRAINING, make_recordings, numeric_versions, pooled_by_environment
from coplane.evaluate.metrics import enu_errors
from coplane.evaluate.runner import run_method
from coplane.methods import get_method
from coplane.recording.reader import Recording


def per_seed(seeds: list[int], recs: list[Recording], method: str, variants: list[str]) -> None:
    """One line per seed: each variant's pooled figures side by side."""
    for seed, rec in zip(seeds, recs, strict=True):
        cells = []
        for v in variants:
            by_env, _ = pooled_by_environment([rec], apply_variant(get_method(method), v))
            a, u = by_env["all"], by_env.get("underpass")
            under = f"{u.h_rmse_m:.2f} / {u.v_rmse_m:.2f}" if u else "-"
            cells.append(f"{a.h_rmse_m:.2f} / {a.v_rmse_m:.2f} | {a.h_p99_m:.1f} | {under}")
        print(f"| {seed} | " + " | ".join(cells) + " |", flush=True)


def trace(rec: Recording, method: str, variants: list[str], worst: int) -> None:
    """Per vehicle: H RMSE under both variants and the epochs where the second lost most."""
    errs: dict[tuple[str, str], dict] = {}
    for v in variants:
        run = run_method(rec, apply_variant(get_method(method), v))
        for veh in rec.manifest.vehicles:
            truth = {t: np.asarray(p) for t, p in rec.truth_at(veh.id).items()}
            times, e = enu_errors(run.positions.get(veh.id, {}), truth)
            errs[(v, veh.id)] = dict(zip(times, np.asarray(e), strict=True))
    a_name, b_name = variants
    for veh in rec.manifest.vehicles:
        env = rec.environment_at(veh.id)
        a, b = errs[(a_name, veh.id)], errs[(b_name, veh.id)]
        ts = sorted(set(a) & set(b))
        ha = np.array([np.hypot(*a[t][:2]) for t in ts])
        hb = np.array([np.hypot(*b[t][:2]) for t in ts])
        print(
            f"\n{veh.id}: H RMSE {a_name} {np.sqrt(np.mean(ha**2)):.2f} m, {b_name} {np.sqrt(np.mean(hb**2)):.2f} m"
        )
        print(f"| epoch | environment | H {a_name} | H {b_name} | up {a_name} | up {b_name} |")
        print("|---|---|---|---|---|---|")
        for i in sorted(np.argsort(-(hb**2 - ha**2))[:worst]):
            t = ts[i]
            print(f"| {i} | {env.get(t)} | {ha[i]:.1f} | {hb[i]:.1f} | {a[t][2]:.1f} | {b[t][2]:.1f} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="dense-urban", choices=sorted(TRAINING))
    ap.add_argument("--method", default="pc")
    ap.add_argument(
        "--variants", default="default,height-links-doppler", help="two bench/tune_fgo.py variants"
    )
    ap.add_argument("--trace", type=int, default=None, help="a training seed to trace epoch by epoch")
    ap.add_argument("--worst", type=int, default=8, help="epochs listed per vehicle")
    ap.add_argument("--duration", type=float, default=200.0)
    args = ap.parse_args()
    variants = args.variants.split(",")
    seeds = list(TRAINING[args.scenario])
    if len(variants) != 2 or (args.trace is not None and args.trace not in seeds):
        ap.error(f"two variants, and --trace one of the training seeds {seeds}")
    print(
        f"`{args.method}` on {args.scenario} training seeds, {variants[0]} | {variants[1]}; {numeric_versions()}\n"
    )
    print("| seed | " + " | ".join(f"{v}: H / V RMSE | H p99 | underpass H / V" for v in variants) + " |")
    print("|---|" + "---|---|---|" * 2)
    with tempfile.TemporaryDirectory() as tmp:
        recs = make_recordings(args.scenario, seeds, Path(tmp), 4, args.duration)
        per_seed(seeds, recs, args.method, variants)
        if args.trace is not None:
            trace(recs[seeds.index(args.trace)], args.method, variants, args.worst)


if __name__ == "__main__":
    main()
