"""Terminal output shared by the commands: the console and the accuracy tables."""

from __future__ import annotations

import os
import sys
from collections.abc import Mapping
from typing import Any

import numpy as np
import typer
from rich.console import Console
from rich.table import Table

PIPE_WIDTH = 160  # columns of a report written to a file or a pipe


def _console(stderr: bool = False) -> Console:
    """Rich's console. Written to a file or a pipe (CI logs, `| tee`), rich assumes 80 columns and
    cuts the tables' labels and headers; there the tables get `PIPE_WIDTH` instead (their natural
    width: rich does not stretch a table). A terminal's own width, or $COLUMNS, still rules."""
    stream = sys.stderr if stderr else sys.stdout
    wide = not stream.isatty() and "COLUMNS" not in os.environ
    return Console(stderr=stderr, width=PIPE_WIDTH if wide else None)


console = _console()
err_console = _console(stderr=True)  # errors and notes: stdout stays the report


def fmt(x: float) -> str:
    return "-" if not np.isfinite(x) else f"{x:.2f}"


def label_column(table: Table, name: str, labels: list[str]) -> None:
    """A first column whose labels (method or vehicle names) are never cut: on a narrow or
    non-terminal console (80 columns, CI logs) rich would shorten `non-cp-ekf` to `non-cp-…`,
    and the numbers' headers wrap instead."""
    table.add_column(name, no_wrap=True, min_width=max([len(name), *map(len, labels)]))


def print_accuracy(title: str, stats: dict, vehicles: list[str]) -> None:
    """One table per vehicle (rows: methods); with a single method, one table (rows: vehicles)."""
    from coplane.evaluate.report import TABLE_COLUMNS

    def row(st: Any) -> list[str]:
        vals = (st.h_rmse_m, st.v_rmse_m, st.cep95_m, st.h_max_m, st.v_max_m)
        return [*(fmt(x) for x in vals), f"{100 * st.availability:.1f}"]

    if not vehicles:  # no truth to measure against: the evaluation's note says so, not an empty table
        return
    if len(stats) == 1:
        ((label, per),) = stats.items()
        table = Table(title=f"{title}: {label}")
        label_column(table, "vehicle", [v for v in vehicles if v in per])
        for col in TABLE_COLUMNS:
            table.add_column(col, justify="right")
        for vid in vehicles:
            if vid in per:
                table.add_row(vid, *row(per[vid]))
        console.print(table)
        return
    for vid in vehicles:
        table = Table(title=f"{title}: vehicle {vid}")
        label_column(table, "method", [label for label, per in stats.items() if vid in per])
        for col in TABLE_COLUMNS:
            table.add_column(col, justify="right")
        for label, per in stats.items():
            if vid in per:
                table.add_row(label, *row(per[vid]))
        console.print(table)


def print_problems(counts: Mapping[str, int]) -> None:
    """One line: how many input problems the reader found, by kind (nothing when there were none).

    Every bad row or epoch is reported where it was found (`--verbose` logs each); this is the
    count a user must not miss after a run that otherwise looks clean.
    """
    total = sum(counts.values())
    if total:
        kinds = sorted(counts.items(), key=lambda kv: (-kv[1], kv[0]))
        console.print(
            f"[yellow]{total} input problems[/yellow]: " + ", ".join(f"{k} x{n}" for k, n in kinds if n)
        )


STRICT_HELP = (
    "Exit with code 3 when nothing was positioned or more than 5 % of the input records had a problem."
)
STRICT_EXIT_CODE = 3  # `--strict` and the input failed health_warnings (README, commands)


def check_input(warnings: list[str], strict: bool) -> None:
    """Print each input warning; under `--strict` any warning ends the command with exit code 3
    (after the outputs were written, so the user can look at them)."""
    for w in warnings:
        err_console.print(f"[yellow]warning:[/yellow] {w}")
    if warnings and strict:
        err_console.print(f"[red]--strict:[/red] exiting with code {STRICT_EXIT_CODE}")
        raise typer.Exit(STRICT_EXIT_CODE)
