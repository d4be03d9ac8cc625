"""Where the dense city's error is: the first seconds of each vehicle, and one vehicle traced
(docs/fgo.md, "A deep-canyon start").

    .venv/bin/python bench/deep_canyon_start.py [--seed 201] [--vehicle u2] [--out docs/fgo.md]

Two tables, both on the dense-urban training seeds (`coplane.evaluate.benchmark.TRAINING`, never
reported; 4 vehicles x 200 s, with the base station):
- `deep_canyon_split`: `pc` and `gamp-cp` pooled over every vehicle of every seed, H / V RMSE
  over all epochs and from the 30th second after each vehicle's first solution on;
- `deep_canyon_trace`: one vehicle second by second: its satellites, the Doppler velocity's up
  component against the truth's, and the vertical error of `pc` (with its reported vertical
  sigma), `pc` with each of the opt-ins `unverified_sigma_scale` = 4 and `motion_last_doppler`,
  and `gamp-cp`;
- `deep_canyon_climb`: the same vehicle when the sky opens (20-40 s), `pc` against `pc` without
  one of what could hold its height back: the robust kernel, the Doppler links' tightness
  (`sigma_v` 0.3 m/s), a free receiver clock in the FDE (`fde_clock_prior` on holds it instead).
Nothing here chooses a default.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
from docblock import publish

from coplane.evaluate.benchmark import TRAINING, make_recordings
from coplane.evaluate.metrics import enu_errors
from coplane.evaluate.runner import run_method
from coplane.evaluate.spp_run import run_spp
from coplane.geo import ecef_to_geodetic, enu_rotation
from coplane.methods import get_method
from coplane.recording.reader import Recording

SCENARIO = "dense-urban"
TRACED = {
    "pc": "pc",
    "pc, unverified_sigma_scale 4": get_method("pc", fgo={"unverified_sigma_scale": 4.0}),
    "pc, motion_last_doppler": get_method("pc", fgo={"motion_last_doppler": True}),
    "gamp-cp": "gamp-cp",
}
CLIMB = {
    "pc": "pc",
    "pc, no robust kernel": get_method("pc", fgo={"robust": None}),
    "pc, sigma_v 0.3": get_method("pc", fgo={"sigma_v": 0.3}),
    "pc, fde_clock_prior": get_method("pc", fgo={"fde_clock_prior": True}),
    "gamp-cp": "gamp-cp",
}


def up_errors(rec: Recording, vid: str, methods: dict[str, Any]) -> dict[str, dict[Any, float]]:
    """Each method's up error of `vid` against the truth, per epoch."""
    truth = {t: np.asarray(p) for t, p in rec.truth_at(vid).items()}
    out: dict[str, dict[Any, float]] = {}
    for name, method in methods.items():
        times, e = enu_errors(run_method(rec, method).positions[vid], truth)
        out[name] = {t: float(x[2]) for t, x in zip(times, e, strict=True)}
    return out


def climb_rows(rec: Recording, vid: str, start: float, end: float) -> list[str]:
    """`vid` from `start` to `end` s after its first epoch: the up error of each CLIMB method."""
    ups = up_errors(rec, vid, CLIMB)
    t0 = min(rec.truth_at(vid))
    rows = ["| s | " + " | ".join(f"{n} up error (m)" for n in CLIMB) + " |", "|---|" + "---|" * len(CLIMB)]
    for t in sorted(ups["pc"]):
        if start <= t - t0 <= end:
            rows.append(
                f"| {t - t0:.0f} | " + " | ".join(f"{ups[n].get(t, float('nan')):+.1f}" for n in CLIMB) + " |"
            )
    return rows


def split_rows(recs: list[Recording]) -> list[str]:
    """Pooled H / V RMSE of pc and gamp-cp, all epochs and from 30 s after each first solution."""
    rows = ["| method | all epochs: H / V RMSE (m) | from 30 s on: H / V RMSE (m) |", "|---|---|---|"]
    for method in ("pc", "gamp-cp"):
        errs: list[tuple[float, float, float]] = []
        for rec in recs:
            run = run_method(rec, method)
            for v in rec.manifest.vehicles:
                truth = {t: np.asarray(p) for t, p in rec.truth_at(v.id).items()}
                times, e = enu_errors(run.positions.get(v.id, {}), truth)
                errs += [
                    (t - times[0], float(np.hypot(x[0], x[1])), float(x[2]))
                    for t, x in zip(times, e, strict=True)
                ]
        a = np.array(errs)
        late = a[:, 0] >= 30.0

        def rms(x: np.ndarray) -> float:
            return float(np.sqrt(np.mean(x**2)))

        rows.append(
            f"| {method} | {rms(a[:, 1]):.2f} / {rms(a[:, 2]):.2f} | {rms(a[late, 1]):.2f} / {rms(a[late, 2]):.2f} |"
        )
    return rows


def trace_rows(rec: Recording, vid: str, start: float, end: float) -> list[str]:
    """The vehicle from `start` to `end` s after its first epoch (see the module docstring)."""
    truth = {t: np.asarray(p) for t, p in rec.truth_at(vid).items()}
    front = run_spp(rec, [vid], dgnss=True)[vid].results
    ups: dict[str, dict[Any, float]] = {}
    sigma: dict[Any, float] = {}
    for name, method in TRACED.items():
        run = run_method(rec, method)
        times, e = enu_errors(run.positions[vid], truth)
        ups[name] = {t: float(x[2]) for t, x in zip(times, e, strict=True)}
        if name == "pc":
            for t in times:
                lat, lon, _ = ecef_to_geodetic(truth[t])
                r = enu_rotation(lat, lon)
                sigma[t] = float(np.sqrt((r @ run.covariances[vid][t] @ r.T)[2, 2]))
    t0 = min(truth)
    rows = [
        "| s | satellites | Doppler up / truth up (m/s) | "
        + " | ".join(f"{n} up error (m)" for n in TRACED)
        + " | pc vertical sigma (m) |",
        "|---|---|---|" + "---|" * len(TRACED) + "---|",
    ]
    for t in sorted(truth):
        if not start <= t - t0 <= end:
            continue
        lat, lon, _ = ecef_to_geodetic(truth[t])
        r = enu_rotation(lat, lon)
        nxt = truth.get(t + 1.0)
        true_up = float((r @ (nxt - truth[t]))[2]) if nxt is not None else float("nan")
        res = front.get(t)
        v = res.velocity if res is not None else None
        dop = f"{float((r @ v.velocity_mps)[2]):+.2f}" if v is not None and v.ok else "-"
        n_sat = len(res.prepared.sats) if res is not None else 0
        errs = " | ".join(f"{ups[n].get(t, float('nan')):+.1f}" for n in TRACED)
        rows.append(
            f"| {t - t0:.0f} | {n_sat} | {dop} / {true_up:+.2f} | {errs} | {sigma.get(t, float('nan')):.1f} |"
        )
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seed", type=int, default=201, help="the traced training seed")
    ap.add_argument("--vehicle", default="u2")
    ap.add_argument("--start", type=float, default=0.0)
    ap.add_argument("--end", type=float, default=50.0)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    if args.seed not in TRAINING[SCENARIO]:
        ap.error(f"--seed {args.seed}: not a dense-urban training seed {TRAINING[SCENARIO]}")
    with tempfile.TemporaryDirectory(prefix="coplane-deep-start-") as tmp:
        recs = make_recordings(SCENARIO, TRAINING[SCENARIO], Path(tmp), 4, 200.0)
        split = split_rows(recs)
        traced = next(r for r in recs if r.manifest.root.name.endswith(f"-{args.seed}"))
        trace = trace_rows(traced, args.vehicle, args.start, args.end)
        climb = climb_rows(traced, args.vehicle, 20.0, 40.0)
    seeds = ", ".join(str(s) for s in TRAINING[SCENARIO])
    cmd = ".venv/bin/python bench/deep_canyon_start.py" + (f" --out {args.out}" if args.out else "")
    publish(
        args.out,
        "deep_canyon_split",
        cmd,
        f"dense-urban training seeds {seeds} (4 vehicles x 200 s, DGNSS), pooled over every vehicle:",
        split,
    )
    publish(
        args.out,
        "deep_canyon_trace",
        cmd,
        f"dense-urban seed {args.seed}, {args.vehicle}, s after its first epoch; satellites the front end "
        "prepared; up errors against the simulator's truth:",
        trace,
    )
    publish(
        args.out,
        "deep_canyon_climb",
        cmd,
        f"dense-urban seed {args.seed}, {args.vehicle}, s after its first epoch, when the sky opens; up "
        "errors against the simulator's truth:",
        climb,
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
