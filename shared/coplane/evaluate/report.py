"""Tables and solution files of `coplane eval` (paper Tables I/II layout, per vehicle)."""

from __future__ import annotations

import csv
import json
import math
from collections import Counter
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from coplane.evaluate.metrics import AccuracyStats, PooledStats, accuracy, accuracy_by_environment
from coplane.evaluate.runner import MethodRun
from coplane.geo import ecef_to_geodetic, enu_rotation
from coplane.gtime import GpsTime
from coplane.messages import plane_source
from coplane.recording.reader import Recording
from coplane.typing import Vec

SOLUTION_COLUMNS = [
    "gps_week",
    "tow_s",
    "x_m",
    "y_m",
    "z_m",
    "cov_xx",
    "cov_yy",
    "cov_zz",
    "cov_xy",
    "cov_yz",
    "cov_xz",
    # how good and why, per epoch: the covariance as local sigmas, what the estimate rests on
    "sigma_h_m",  # sqrt(var east + var north)
    "sigma_v_m",
    "n_satellites",  # used by the vehicle's SPP
    "n_pseudoranges",  # of those, kept by the estimator (the rest its FDE excluded)
    "excluded",  # the ones it left out, space-separated (e.g. "C07 G12")
    "n_ranges",
    "gnss_fix",
    "plane",  # used, or the plane's status when not used (available, unavailable: reason), or none
    "plane_source",  # fleet, self or map
    "raim_excluded",  # what the agent's RAIM excluded before the estimator saw the epoch
    "hdop",  # of the satellites the agent's fix used
    "vdop",
]


def run_stats(run: MethodRun, rec: Recording) -> dict[str, AccuracyStats]:
    """Accuracy of every vehicle that has truth."""
    out: dict[str, AccuracyStats] = {}
    for v in rec.manifest.vehicles:
        truth = rec.truth_at(v.id)
        if truth:
            out[v.id] = accuracy(run.positions.get(v.id, {}), {t: np.asarray(p) for t, p in truth.items()})
    return out


def write_solutions(run: MethodRun, out_dir: Path) -> list[Path]:
    """DIR/solutions/<method>[@r<rate>]/<vehicle>.csv in the truth layout plus covariance columns."""
    folder = out_dir / "solutions" / run.label
    folder.mkdir(parents=True, exist_ok=True)
    written = []
    for vid, pos in sorted(run.positions.items()):
        path = folder / f"{vid}.csv"
        covs = run.covariances.get(vid, {})
        with path.open("w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(SOLUTION_COLUMNS)
            for t in sorted(pos):
                p = pos[t]
                c = covs.get(t)
                cc = [c[0, 0], c[1, 1], c[2, 2], c[0, 1], c[1, 2], c[0, 2]] if c is not None else [""] * 6
                w.writerow(
                    [
                        t.week,
                        f"{t.tow:.3f}",
                        f"{p[0]:.4f}",
                        f"{p[1]:.4f}",
                        f"{p[2]:.4f}",
                        *(f"{x:.6g}" if x != "" else "" for x in cc),
                        *_why(run, vid, t, p, c),
                    ]
                )
        written.append(path)
    return written


def _why(run: MethodRun, vid: str, t: GpsTime, p: Vec, cov: Vec | None) -> list[str]:
    """The per-epoch columns after the covariance; blank where the method does not say (RTKLIB)."""
    sigmas = ["", ""]
    if cov is not None:
        lat, lon, _ = ecef_to_geodetic(p)
        r = enu_rotation(lat, lon)
        enu = r @ cov @ r.T
        sigmas = [
            f"{math.sqrt(max(enu[0, 0] + enu[1, 1], 0.0)):.3f}",
            f"{math.sqrt(max(enu[2, 2], 0.0)):.3f}",
        ]

    def count(table: dict[str, dict[GpsTime, int]]) -> str:
        n = table.get(vid, {}).get(t)
        return "" if n is None else str(n)

    fix = run.gnss_fix.get(vid, {}).get(t)
    used = run.plane_used.get(vid, {}).get(t)
    plane = run.plane_summaries.get(vid, {}).get(t)
    if used:
        state = "used"
    elif plane is None:
        state = "" if used is None else "none"
    else:
        state = plane.status if plane.status != "unavailable" else f"unavailable: {plane.reason or '-'}"
    source = plane_source(plane) or ""
    hdop, vdop = run.dops.get(vid, {}).get(t, (None, None))
    return [
        *sigmas,
        count(run.satellites),
        count(run.pseudoranges_used),
        " ".join(run.excluded.get(vid, {}).get(t, ())),
        count(run.ranges_used),
        "" if fix is None else str(int(fix)),
        state,
        source,
        " ".join(run.raim_excluded.get(vid, {}).get(t, ())),
        "" if hdop is None else f"{hdop:.2f}",
        "" if vdop is None else f"{vdop:.2f}",
    ]


TABLE_COLUMNS = ("H RMSE (m)", "V RMSE (m)", "CEP95 (m)", "Max HPE (m)", "Max VPE (m)", "Avail (%)")


def _row(st: AccuracyStats) -> list[str]:
    vals = [st.h_rmse_m, st.v_rmse_m, st.cep95_m, st.h_max_m, st.v_max_m]
    return [("-" if not math.isfinite(x) else f"{x:.2f}") for x in vals] + [f"{100 * st.availability:.1f}"]


def markdown_table(stats: dict[str, dict[str, AccuracyStats]], vehicle: str) -> str:
    """One Table-I-style table for one vehicle: a row per method label."""
    lines = [
        f"| Method ({vehicle}) | " + " | ".join(TABLE_COLUMNS) + " |",
        "|---" * (len(TABLE_COLUMNS) + 1) + "|",
    ]
    for label, per in stats.items():
        if vehicle in per:
            lines.append(f"| {label} | " + " | ".join(_row(per[vehicle])) + " |")
    return "\n".join(lines)


def write_tables(
    stats: dict[str, dict[str, AccuracyStats]],
    vehicles: Sequence[str],
    out_dir: Path,
    extra: dict[str, Any] | None = None,
) -> Path:
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "accuracy.json").write_text(
        json.dumps(
            {
                "methods": {lab: {v: s.as_dict() for v, s in per.items()} for lab, per in stats.items()},
                **(extra or {}),
            },
            indent=2,
            default=lambda x: None if isinstance(x, float) and not math.isfinite(x) else x,
        )
    )
    md = "\n\n".join(markdown_table(stats, v) for v in vehicles)
    notes = (extra or {}).get("notes") or {}
    if notes:  # what the numbers rest on (the truth used, the RTKLIB mode, changed settings)
        md += "\n\n" + "\n".join(f"- {key}: {text}" for key, text in notes.items())
    path = out_dir / "accuracy.md"
    path.write_text(md + "\n")
    return path


def environment_stats(run: MethodRun, rec: Recording) -> dict[str, PooledStats]:
    """The run's errors pooled over vehicles, overall and per environment of the truth."""
    ids = [v.id for v in rec.manifest.vehicles if rec.truth_at(v.id)]
    truth = {vid: {t: np.asarray(p) for t, p in rec.truth_at(vid).items()} for vid in ids}
    return accuracy_by_environment(run.positions, truth, {vid: rec.environment_at(vid) for vid in ids})


def environment_table(by_env: dict[str, dict[str, PooledStats]]) -> str:
    """Pooled H / V RMSE per environment, then the tail (p50, p99, max) over all epochs and the
    signed mean vertical error (a bias, which RMSE does not separate from scatter)."""
    envs: list[str] = []
    for per in by_env.values():
        envs += [e for e in per if e not in envs]
    first = next(iter(by_env.values()), {})
    head = [f"{e} ({first[e].n} ep.)" if e in first else e for e in envs]
    lines = [
        "| Method | "
        + " | ".join(f"{h} H / V RMSE (m)" for h in head)
        + " | H p50 / p99 / max (m) | V mean (m) |",
        "|---" * (len(envs) + 3) + "|",
    ]

    def f(x: float) -> str:
        return "-" if not math.isfinite(x) else f"{x:.2f}"

    for label, per in by_env.items():
        cells = [f"{f(per[e].h_rmse_m)} / {f(per[e].v_rmse_m)}" if e in per else "-" for e in envs]
        a = per.get("all")
        tail = f"{f(a.h_p50_m)} / {f(a.h_p99_m)} / {f(a.h_max_m)}" if a is not None else "-"
        bias = "-" if a is None or not math.isfinite(a.v_mean_m) else f"{a.v_mean_m:+.2f}"
        lines.append(f"| {label} | " + " | ".join(cells) + f" | {tail} | {bias} |")
    return "\n".join(lines)


def write_environment_tables(by_env: dict[str, dict[str, PooledStats]], out_dir: Path) -> Path:
    """accuracy_by_environment.json and .md beside accuracy.json."""
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "accuracy_by_environment.json").write_text(
        json.dumps(
            {lab: {e: s.as_dict() for e, s in per.items()} for lab, per in by_env.items()},
            indent=2,
            default=lambda x: None if isinstance(x, float) and not math.isfinite(x) else x,
        )
    )
    path = out_dir / "accuracy_by_environment.md"
    path.write_text(environment_table(by_env) + "\n")
    return path


def exclusion_table(runs: Sequence[MethodRun], top: int = 5) -> str:
    """Per method and vehicle, which satellites the estimator left out and how often: the epochs
    with any left out, the total, and the `top` satellites left out most. Why an epoch's estimate
    rests on fewer satellites than its agent used is per epoch in the solution CSVs ("excluded");
    a satellite that tops this table over a whole drive is a reflector's or a bad signal's mark."""
    lines = [
        "| Method | vehicle | epochs | epochs with satellites left out | satellites left out | most often (times) |",
        "|---|---|---|---|---|---|",
    ]
    for run in runs:
        for vid in sorted(run.excluded):
            per_epoch = run.excluded[vid]
            counts = Counter(s for sats in per_epoch.values() for s in sats)
            most = ", ".join(
                f"{s} ({n})" for s, n in sorted(counts.items(), key=lambda x: (-x[1], x[0]))[:top]
            )
            lines.append(
                f"| {run.label} | {vid} | {len(per_epoch)} | {sum(1 for x in per_epoch.values() if x)} | "
                f"{sum(counts.values())} | {most or '-'} |"
            )
    return "\n".join(lines)


def write_exclusions(runs: Sequence[MethodRun], out_dir: Path) -> Path:
    """exclusions.md beside accuracy.md (`exclusion_table`)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / "exclusions.md"
    path.write_text(exclusion_table(runs) + "\n")
    return path
