"""Compare factor-graph settings against the baselines on the TRAINING seeds only (robust fusion).

    .venv/bin/python bench/tune_fgo.py                       # training set, every variant, ~25 min
    .venv/bin/python bench/tune_fgo.py --methods pc --variants default,no-fde --duration 120

Defaults are chosen on these seeds and reported on others: the training set is
`coplane.evaluate.benchmark.TRAINING` and must never be used for docs/results.md (which reports
`HELD_OUT`). Each variant changes the method's current defaults (`ROBUST_FGO`); prints pooled
(all vehicles, all recordings) H/V RMSE, the horizontal median, p99 and maximum, and the same
pooled per environment of the truth (the simulator's road sections). The comparison these
defaults came from is in docs/fgo.md ("Robust defaults").
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
from pathlib import Path

from coplane.evaluate.benchmark import TRAINING, make_recordings, pooled_by_environment
from coplane.evaluate.metrics import PooledStats
from coplane.methods import get_method

VARIANTS: dict[str, dict[str, object]] = {
    "default": {},
    "paper-window": {"solver": "lm-window"},  # the paper's LM window + anchors instead of iSAM2
    "no-fde": {"fde_k": None},
    "gate3-no-fde": {"fde_k": None, "gate_k": 3.0},
    "cauchy": {"robust": "cauchy"},
    "sigma-v-0.2": {"sigma_v": 0.2},
    "sigma-v-0.6": {"sigma_v": 0.6},
    "pr-sigma-x2": {"pseudorange_sigma_scale": 2.0},
    "no-range-warmup": {"range_warmup_epochs": 0},
}


def line(by_env: dict[str, PooledStats]) -> str:
    a = by_env["all"]
    parts = [
        f"H {a.h_rmse_m:6.2f} V {a.v_rmse_m:6.2f} p50 {a.h_p50_m:5.2f} p99 {a.h_p99_m:6.2f} max {a.h_max_m:6.1f}"
    ]
    parts += [f"{e} {s.h_rmse_m:.2f}/{s.v_rmse_m:.2f}" for e, s in by_env.items() if e != "all"]
    return " | ".join(parts)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--methods", default="non-cp-ekf,gamp-cp,non-cp,mci,pc")
    ap.add_argument("--variants", default=",".join(VARIANTS))
    ap.add_argument("--duration", type=float, default=300.0)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        recs = [
            rec
            for scen, seeds in TRAINING.items()
            for rec in make_recordings(scen, seeds, Path(tmp), 4, args.duration)
        ]
        for m in args.methods.split(","):
            base = get_method(m)
            for name in args.variants.split(",") if base.fgo is not None else ["-"]:
                spec = base
                if base.fgo is not None:
                    spec = dataclasses.replace(base, fgo=dataclasses.replace(base.fgo, **VARIANTS[name]))  # type: ignore[arg-type]
                by_env, cons = pooled_by_environment(recs, spec)
                print(
                    f"{m:11s} {name:16s} {line(by_env)} | in95 H {cons.h_in95:.2f} V {cons.v_in95:.2f}",
                    flush=True,
                )


if __name__ == "__main__":
    main()
