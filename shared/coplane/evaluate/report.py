"""Tables and solution files of `coplane eval` (paper Tables I/II layout, per vehicle)."""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from coplane.evaluate.metrics import AccuracyStats, accuracy
from coplane.evaluate.runner import MethodRun
from coplane.recording.reader import Recording

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
                    ]
                )
        written.append(path)
    return written


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
    path = out_dir / "accuracy.md"
    path.write_text(md + "\n")
    return path
