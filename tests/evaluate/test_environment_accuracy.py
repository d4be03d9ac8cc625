"""Accuracy per environment: the truth's section labels reach the pooled tables, tails included."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from coplane.evaluate.metrics import accuracy_by_environment, pooled_stats
from coplane.evaluate.report import environment_table
from coplane.geo import enu_rotation, geodetic_to_ecef
from coplane.gtime import GpsTime
from coplane.recording.csvfiles import read_truth
from coplane.recording.problems import Problems

LAT, LON = math.radians(39.9), math.radians(116.4)
REF = geodetic_to_ecef(LAT, LON, 50.0)
ROT = enu_rotation(LAT, LON)


def _at(e: float, n: float, u: float) -> np.ndarray:
    return REF + ROT.T @ np.array([e, n, u])


def test_truth_reader_keeps_the_section_or_environment_column(tmp_path: Path) -> None:
    """`section` (the simulator's) or `environment` becomes TruthPoint.environment; none gives ""."""
    x, y, z = REF
    for column, expected in (("section", "deep"), ("environment", "underpass"), ("lane", "")):
        p = tmp_path / f"{column}.csv"
        p.write_text(f"gps_week,tow_s,x_m,y_m,z_m,{column}\n2300,10.0,{x},{y},{z},{expected or '1'}\n")
        (pt,) = read_truth(p, Problems())
        assert pt.environment == expected


def test_a_malformed_environment_label_is_reported_and_the_row_kept(tmp_path: Path) -> None:
    """A label that is not a short word is dropped with a file:line problem; the position stays."""
    x, y, z = REF
    p = tmp_path / "t.csv"
    p.write_text(f"gps_week,tow_s,x_m,y_m,z_m,environment\n2300,10.0,{x},{y},{z},deep canyon!\n")
    problems = Problems()
    (pt,) = read_truth(p, problems)
    assert pt.environment == "" and pt.ecef_m == (x, y, z)
    assert problems.counts["malformed-value"] == 1
    assert "t.csv:2" in str(problems.items[0]) and "deep canyon!" in str(problems.items[0])


def test_pooled_by_environment_with_tail() -> None:
    """Errors are pooled over vehicles per label, "all" first then open..underpass, p99 and max kept."""
    times = [GpsTime(2300, 100.0 + k) for k in range(4)]
    truth = {v: {t: REF for t in times} for v in ("a", "b")}
    sol = {
        "a": {
            times[0]: _at(1, 0, 0),
            times[1]: _at(0, 2, 0),
            times[2]: _at(3, 0, 1),
            times[3]: _at(0, 0, -2),
        },
        "b": {times[0]: _at(0, 1, 0), times[1]: _at(20, 0, 0)},  # epochs 2, 3 unsolved
    }
    env = {v: dict(zip(times, ["open", "open", "deep", "underpass"], strict=True)) for v in ("a", "b")}
    out = accuracy_by_environment(sol, truth, env)
    assert list(out) == ["all", "open", "deep", "underpass"]
    assert out["all"].n == 6 and out["open"].n == 4 and out["deep"].n == 1
    assert out["open"].h_rmse_m == pytest.approx(math.sqrt((1 + 4 + 1 + 400) / 4))
    assert out["all"].h_max_m == pytest.approx(20.0)
    assert out["underpass"].v_rmse_m == pytest.approx(2.0)
    assert math.isnan(pooled_stats(np.zeros((0, 3))).h_rmse_m)
    table = environment_table({"m": out})
    assert "| m | " in table and "open (4 ep.)" in table and "/ 20.00 |" in table
    # the signed mean vertical error over all epochs: (0 + 0 + 1 - 2 + 0 + 0) / 6
    assert out["all"].v_mean_m == pytest.approx(-1.0 / 6.0)
    assert table.splitlines()[2].endswith("| -0.17 |") and "V mean (m)" in table
