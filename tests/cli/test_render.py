"""The command line's tables: method and vehicle names are never cut, on a narrow terminal or
written to a file or a pipe (CI logs, `| tee`), where rich would otherwise assume 80 columns."""

from __future__ import annotations

import io

import pytest
from rich.console import Console

from coplane.cli import render
from coplane.evaluate.metrics import AccuracyStats

STATS = AccuracyStats(600, 600, 1.0, 1.42, 1.34, 2.34, 2.85, 4.09, 1.1, 0.1)


def test_names_are_not_cut_on_an_80_column_console(monkeypatch: pytest.MonkeyPatch) -> None:
    out = io.StringIO()
    monkeypatch.setattr(render, "console", Console(file=out, width=80))
    stats = {m: {"a-long-vehicle-id": STATS} for m in ("non-cp", "non-cp-ekf", "gamp-cp@r40")}
    render.print_accuracy("a recording with a long title", stats, ["a-long-vehicle-id"])
    text = out.getvalue()
    assert all(m in text for m in ("non-cp-ekf", "gamp-cp@r40", "a-long-vehicle-id")), text
    assert "…" not in text
    one = io.StringIO()
    monkeypatch.setattr(render, "console", Console(file=one, width=40))
    render.print_accuracy("one method", {"non-cp-ekf": {"a-long-vehicle-id": STATS}}, ["a-long-vehicle-id"])
    assert "a-long-vehicle-id" in one.getvalue()


def test_a_console_that_is_not_a_terminal_is_wide_unless_columns_says(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.delenv("COLUMNS", raising=False)
    monkeypatch.setattr("sys.stdout", io.StringIO())  # not a terminal
    assert render._console().width == render.PIPE_WIDTH
    monkeypatch.setenv("COLUMNS", "100")
    assert render._console().width == 100
