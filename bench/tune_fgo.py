"""Compare factor-graph settings against the baselines on the TRAINING seeds only (robust fusion).

    .venv/bin/python bench/tune_fgo.py --out docs/tuning.md   # every variant, ~25 min on 2 cores
    .venv/bin/python bench/tune_fgo.py --runs pc:default,pc:no-fde --duration 120

Defaults are chosen on these seeds and reported on others: the training set is
`coplane.evaluate.benchmark.TRAINING` and must never be used for docs/results.md (which reports
`HELD_OUT`). `--validation` runs on `VALIDATION` instead: the seeds that check a choice the
training seeds won but could not settle (never reported either); `--exploration` on
`EXPLORATION`, the simulator's other scenarios (a city, an open sky), where a candidate may be
found (never reported either). `--standalone` runs every method
without the recordings' base station; `--no-doppler` on the same drives recorded without Doppler. Each variant changes the method's current defaults
(`ROBUST_FGO`, or the plane step's `PlaneConfig` for a `PLANE_VARIANTS` name); prints pooled
(all vehicles, all recordings) H/V RMSE, the horizontal median, p99 and maximum, and the same
pooled per environment of the truth (the simulator's road sections). The comparison these
defaults came from is in docs/fgo.md ("Robust defaults").
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime as dt
import sys
import tempfile
from pathlib import Path

from fgo_variants import BASELINE_VARIANTS, PLANE_VARIANTS, SLOW_VARIANTS, VARIANTS

from coplane.evaluate.benchmark import (
    EXPLORATION,
    TRAINING,
    VALIDATION,
    Consistency,
    make_recordings,
    numeric_versions,
    pooled_by_environment,
)
from coplane.evaluate.front_ends import FrontEndMemo
from coplane.evaluate.metrics import PooledStats
from coplane.methods import MethodSpec, get_method
from coplane.plane.config import PlaneConfig

DEFAULT_RUNS = (
    [("pc", v) for v in VARIANTS if v not in SLOW_VARIANTS]
    + [("mci", "default"), ("non-cp", "default")]
    + [(m, v) for m in ("non-cp-ekf", "dd-cp", "gamp-cp") for v in BASELINE_VARIANTS]
)


def apply_variant(spec: MethodSpec, variant: str) -> MethodSpec:
    """`spec` with a VARIANTS entry applied to its factor graph, or a BASELINE_VARIANTS entry to a
    baseline; `a+b` applies both (b's settings win where they overlap); an unknown name raises
    KeyError."""
    if spec.fgo is None:
        return dataclasses.replace(spec, **BASELINE_VARIANTS[variant])  # type: ignore[arg-type]
    changes = {k: v for part in variant.split("+") for k, v in VARIANTS[part].items()}
    return dataclasses.replace(spec, fgo=dataclasses.replace(spec.fgo, **changes))  # type: ignore[arg-type]


def split_plane_variant(variant: str) -> tuple[str, PlaneConfig | None]:
    """`variant` ('a+b') split into what `apply_variant` takes (the VARIANTS or BASELINE_VARIANTS
    parts, '' when none) and the PlaneConfig its PLANE_VARIANTS parts ask for (None: the default
    plane step), so that a graph setting and a plane setting combine in one run."""
    parts = variant.split("+")
    plane = {k: v for part in parts if part in PLANE_VARIANTS for k, v in PLANE_VARIANTS[part].items()}
    rest = "+".join(part for part in parts if part not in PLANE_VARIANTS)
    return rest, (PlaneConfig(**plane) if plane else None)  # type: ignore[arg-type]


def row(method: str, variant: str, by_env: dict[str, PooledStats], cons: Consistency) -> str:
    """One Markdown row: pooled H/V RMSE, tail, deep canyon, underpass, the 95 % containment and
    the mean NEES."""
    a = by_env["all"]
    env = [
        f"{s.h_rmse_m:.2f} / {s.v_rmse_m:.2f}" if (s := by_env.get(k)) else "-" for k in ("deep", "underpass")
    ]
    return (
        f"| {method} | {variant} | {a.h_rmse_m:.2f} / {a.v_rmse_m:.2f} | {a.v_mean_m:+.2f} "
        f"| {a.h_p99_m:.2f} / {a.h_max_m:.1f} | {env[0]} | {env[1]} | {cons.h_in95:.2f} / {cons.v_in95:.2f} | {cons.nees:.2f} |"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--runs", default="", help="method:variant[+variant],... (default: every pc variant + the others)"
    )
    ap.add_argument("--duration", type=float, default=200.0)
    ap.add_argument("--out", type=Path, default=None, help="also write the table here (docs/tuning.md)")
    ap.add_argument(
        "--seeds",
        action="append",
        default=[],
        metavar="SCENARIO=S1,S2",
        help="only these training seeds of a scenario (repeatable; for slow variants such as GNC)",
    )
    ap.add_argument(
        "--validation", action="store_true", help="the validation seeds instead of the training ones"
    )
    ap.add_argument(
        "--standalone",
        action="store_true",
        help="every method without the recordings' base station (no DGNSS), as docs/results.md's standalone section",
    )
    ap.add_argument(
        "--no-doppler",
        action="store_true",
        help="the same drives recorded without Doppler (a receiver or stream that gives none)",
    )
    ap.add_argument(
        "--exploration",
        action="store_true",
        help="the seeds of the other scenarios (city, open sky) instead of the training ones",
    )
    args = ap.parse_args()
    if args.validation and args.exploration:
        ap.error("--validation and --exploration are two seed sets: pick one")
    training = dict(VALIDATION if args.validation else EXPLORATION if args.exploration else TRAINING)
    if args.seeds and (args.validation or args.exploration):
        ap.error("--seeds picks training seeds; --validation / --exploration run every seed of their set")
    if args.seeds:
        training = {}
        for item in args.seeds:
            scen, _, seeds = item.partition("=")
            chosen = [int(x) for x in seeds.split(",") if x]
            if scen not in TRAINING or not set(chosen) <= set(TRAINING[scen]) or not chosen:
                ap.error(f"--seeds {item!r}: not a subset of the training seeds {TRAINING}")
            training[scen] = chosen
    runs = [tuple(r.split(":")) for r in args.runs.split(",")] if args.runs else DEFAULT_RUNS
    for run in runs:  # a typo fails here, not after the first scenario's minutes of runs
        if len(run) != 2:
            ap.error(f"--runs {':'.join(run)!r}: not method:variant[+variant]")
        m, name = run
        try:
            rest = split_plane_variant(name)[0]
            apply_variant(get_method(m), rest) if rest else get_method(m)
        except (ValueError, KeyError) as exc:  # ConfigError (unknown method) is a ValueError
            what = f"unknown variant {exc}" if isinstance(exc, KeyError) else str(exc)
            ap.error(
                f"--runs {':'.join(run)!r}: {what} (method:variant[+variant], see bench/fgo_variants.py)"
            )
    kind = "validation" if args.validation else "exploration" if args.exploration else "training"
    mode = ", without a base station (standalone)" if args.standalone else ""
    mode += ", recorded without Doppler" if args.no_doppler else ""
    lines = [
        f"# Tuning on the {kind} seeds{mode}\n",
        f"Output of `.venv/bin/python bench/tune_fgo.py {' '.join(sys.argv[1:])}` ({dt.date.today()}): "
        f"{', '.join(f'{k} {v}' for k, v in training.items())}, 4 vehicles x {args.duration:.0f} s, "
        "pooled over the vehicles and seeds of each scenario. Each variant changes the current defaults "
        "(`ROBUST_FGO`, docs/fgo.md) in one respect. These seeds are never reported: "
        "docs/results.md uses held-out ones. In95: share of epochs inside the reported 95 % region; NEES: the mean "
        "normalised estimation error squared, 3-D (3 if the covariance is honest). "
        f"Made with {numeric_versions()}.\n",
    ]
    print("\n".join(lines), flush=True)
    header = [
        "| method | variant | H / V RMSE (m) | V mean (m) | H p99 / max (m) | deep canyon H / V RMSE (m) "
        "| underpass H / V RMSE (m) | in95 H / V | NEES |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    dgnss = False if args.standalone else None  # None: with the recordings' base
    # every variant's GNSS front ends are the same: computed once per seed, and then one process per
    # run is faster than vehicle workers (which would only build the node messages)
    memo = FrontEndMemo()
    with tempfile.TemporaryDirectory() as tmp:
        for scen, seeds in training.items():
            recs = make_recordings(scen, seeds, Path(tmp), 4, args.duration, not args.no_doppler)
            lines += [f"\n## `{scen}`, seeds {', '.join(map(str, seeds))}\n", *header]
            print("\n".join(lines[-3:]), flush=True)
            for m, name in runs:
                rest, plane = split_plane_variant(name)
                spec = apply_variant(get_method(m), rest) if rest else get_method(m)
                stats = pooled_by_environment(
                    recs, spec, jobs=1, dgnss=dgnss, plane_config=plane, front_ends=memo
                )
                lines.append(row(m, name, *stats))
                print(lines[-1], flush=True)
    if args.out is not None:
        args.out.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
