"""`coplane spp`: single point positioning of each vehicle of a recording."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import numpy as np
import typer
from rich.table import Table

from coplane.cli.render import console, fmt


def spp(
    recording: Annotated[Path, typer.Argument(help="Fleet recording directory (with fleet.toml).")],
    out: Annotated[
        Path,
        typer.Option(help="RTKLIB .pos file; with several vehicles, one file per vehicle (<stem>_<id>.pos)."),
    ],
    vehicle: Annotated[list[str] | None, typer.Option(help="Vehicle id (repeatable); default all.")] = None,
    dgnss: Annotated[
        bool, typer.Option(help="Apply DGNSS corrections from the recording's base station.")
    ] = False,
    fde: Annotated[bool, typer.Option(help="RAIM fault detection and exclusion.")] = True,
) -> None:
    """Single point positioning of each vehicle; writes .pos and prints availability and accuracy."""
    from dataclasses import replace

    from coplane.evaluate.metrics import accuracy
    from coplane.evaluate.solution_files import Q_DGPS, Q_SINGLE, PosRecord, write_pos
    from coplane.evaluate.spp_run import run_spp
    from coplane.gnss.epoch_solver import EpochSolverOptions
    from coplane.recording.problems import RecordingError
    from coplane.recording.reader import open_recording

    try:
        rec = open_recording(recording)
        opts = EpochSolverOptions()
        opts = replace(opts, spp=replace(opts.spp, raim="fde" if fde else "off"))
        runs = run_spp(rec, vehicle, dgnss=dgnss, options=opts, progress=True)
    except (RecordingError, KeyError, ValueError) as exc:
        console.print(f"[red]error:[/red] {exc}")
        raise typer.Exit(2) from exc
    table = Table(title=f"SPP {'DGNSS' if dgnss else 'standalone'}: {rec.manifest.name}")
    for col in (
        "vehicle",
        "epochs",
        "fixes",
        "avail %",
        "H RMSE m",
        "V RMSE m",
        "CEP95 m",
        "max H m",
        "max V m",
        "no fix: reasons",
    ):
        table.add_column(col, justify="right" if col not in ("vehicle", "no fix: reasons") else "left")
    for vid, run in runs.items():
        fixes = run.fixes()
        target = out if len(runs) == 1 else out.with_name(f"{out.stem}_{vid}{out.suffix or '.pos'}")
        write_pos(
            target,
            (
                PosRecord(
                    r.spp.time, r.spp.position, r.spp.covariance, Q_DGPS if dgnss else Q_SINGLE, r.spp.n_used
                )
                for r in run.results.values()
                if r.spp.ok
            ),
            inputs=[str(rec.manifest.vehicle(vid).obs)],
            mode="dgps" if dgnss else "single",
        )
        truth = rec.truth_at(vid)
        st = accuracy(fixes, {t: np.asarray(p) for t, p in truth.items()}) if truth else None
        avail = 100.0 * len(fixes) / run.n_epochs if run.n_epochs else 0.0
        reasons = ", ".join(f"{k} x{n}" for k, n in run.no_solution.most_common(3))
        table.add_row(
            vid,
            str(run.n_epochs),
            str(len(fixes)),
            f"{avail:.1f}",
            *(
                fmt(x)
                for x in (
                    (st.h_rmse_m, st.v_rmse_m, st.cep95_m, st.h_max_m, st.v_max_m) if st else (np.nan,) * 5
                )
            ),
            reasons or "-",
        )
        console.print(f"wrote {target}")
    console.print(table)
    if rec.problems:
        console.print(
            f"[yellow]{rec.problems.total} input problems[/yellow]: "
            + ", ".join(f"{k} x{n}" for k, n in rec.problems.counts.most_common())
        )
