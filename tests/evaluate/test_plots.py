"""The eval figures when there is nothing to draw (a truth of another day, a run that solved nothing)."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from coplane.evaluate.plots import plot_cdfs, plot_error_vs_time
from coplane.evaluate.runner import MethodRun
from coplane.gtime import GpsTime


def test_a_figure_without_errors_says_why_and_warns_nothing(tmp_path: Path) -> None:
    """A solution and a truth with no epoch in common: the figures are written, without
    matplotlib's 'No artists with labels' warning that `coplane eval` used to print."""
    run = MethodRun("non-cp", 0.0)
    run.positions["u1"][GpsTime(2161, 100.0)] = np.array([-2.4e6, 5.38e6, 2.4e6])
    truth = {GpsTime(2158, 100.0): np.array([-2.4e6, 5.38e6, 2.4e6])}
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        paths = [*plot_cdfs([run], truth, "u1", tmp_path), plot_error_vs_time([run], truth, "u1", tmp_path)]
    assert all(p.is_file() and p.stat().st_size > 0 for p in paths)
