"""`coplane spp`: single point positioning of each vehicle of a recording."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import numpy as np
import typer
from rich.table import Table

from coplane.cli.options import progress_bars
from coplane.cli.render import STRICT_HELP, check_input, console, fmt, label_column, print_problems

COLUMNS = (
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
)


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
    strict: Annotated[bool, typer.Option(help=STRICT_HELP)] = False,
    truth: Annotated[
        list[str] | None,
        typer.Option(
            help="What the accuracy is measured against, as with `coplane eval`: 'recording' (the default),"
            " 'rtk', ID=FILE (a reference trajectory) or ID=x,y,z / ID=lat,lon,h (a surveyed point).",
        ),
    ] = None,
) -> None:
    """Single point positioning of each vehicle; writes .pos and prints availability and accuracy."""
    from coplane.evaluate.spp_run import spp_to_pos
    from coplane.evaluate.truth import parse_truth_choice
    from coplane.recording.health import health_warnings

    choice = parse_truth_choice(truth)
    report = spp_to_pos(recording, out, vehicle, dgnss=dgnss, fde=fde, progress=progress_bars(), truth=choice)
    if report.truth_note:
        typer.echo(report.truth_note, err=True)
    table = Table(title=f"SPP {'DGNSS' if report.dgnss else 'standalone'}: {report.recording}")
    label_column(table, COLUMNS[0], [v.vehicle for v in report.vehicles])
    for col in COLUMNS[1:]:
        table.add_column(col, justify="left" if col == "no fix: reasons" else "right")
    for v in report.vehicles:
        st = v.accuracy
        reasons = ", ".join(f"{k} x{n}" for k, n in v.no_solution.most_common(3))
        table.add_row(
            v.vehicle,
            str(v.n_epochs),
            str(v.n_fixes),
            f"{v.availability_pct:.1f}",
            *(
                fmt(x)
                for x in (
                    (st.h_rmse_m, st.v_rmse_m, st.cep95_m, st.h_max_m, st.v_max_m) if st else (np.nan,) * 5
                )
            ),
            reasons or "-",
        )
        console.print(f"wrote {v.pos_path}")
    console.print(table)
    print_problems(report.problems)
    check_input(health_warnings(report.health, sum(v.n_fixes for v in report.vehicles)), strict)
