"""Helpers of the benchmark scripts that decide what a regenerated page of docs/ measured: which
plane step a tuning run used (`bench/tune_fgo.py`) and which commits an A/B compares
(`bench/bench_scale_ab.py`). The scripts themselves take minutes and are only imported elsewhere
(tests/core/test_bench_scripts.py)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from coplane.plane.config import PlaneConfig

BENCH = Path(__file__).resolve().parents[2] / "bench"


@pytest.fixture
def bench_path(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.syspath_prepend(str(BENCH))  # the scripts import each other from bench/


def test_a_plane_variant_combines_with_a_graph_variant(bench_path: None) -> None:
    import tune_fgo

    assert tune_fgo.split_plane_variant("default") == ("default", None)
    rest, plane = tune_fgo.split_plane_variant("cauchy+plane-sigma-offset")
    assert rest == "cauchy" and plane == PlaneConfig(sigma_model="offset")
    assert tune_fgo.split_plane_variant("plane-sigma-covariance") == (
        "",
        PlaneConfig(sigma_model="covariance"),
    )
    with pytest.raises(KeyError):  # an unknown name still fails where apply_variant looks it up
        tune_fgo.apply_variant(tune_fgo.get_method("pc"), tune_fgo.split_plane_variant("nonsense")[0])


def test_ab_names_a_revision_git_cannot_resolve(bench_path: None) -> None:
    import bench_scale_ab

    head = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], cwd=BENCH, capture_output=True, text=True, check=True
    ).stdout.strip()
    assert bench_scale_ab._short("HEAD") == head
    with pytest.raises(SystemExit, match="'no-such-rev' is not a commit of this repository"):
        bench_scale_ab._short("no-such-rev")


def test_tune_fgo_refuses_a_run_it_cannot_make_before_running_any() -> None:
    for runs, says in (("pc:nonsense", "unknown variant 'nonsense'"), ("pc", "not method:variant")):
        proc = subprocess.run(
            [sys.executable, str(BENCH / "tune_fgo.py"), "--runs", runs],
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert proc.returncode == 2 and says in proc.stderr, proc.stderr[-500:]


def test_a_results_header_names_the_blas_kernels() -> None:
    """The numeric libraries and every loaded BLAS with the kernels it picked (docs/results.md's
    and the tuning tables' headers), so that runs on different kernels can be told apart."""
    import numpy as np

    from coplane.evaluate.benchmark import numeric_versions

    np.linalg.inv(np.eye(3))  # numpy's BLAS is loaded with numpy itself; this only uses it
    text = numeric_versions()
    assert text.startswith("gtsam ") and "numpy " in text and "scipy " in text
    assert "blas" in text.lower()


def test_the_memory_table_gives_the_second_half_trend_per_10_minutes_of_the_drive(bench_path: None) -> None:
    """The 30-minute memory table's growth is a least-squares slope over the second half, scaled
    from wall time to the drive's time (a lockstep run is faster than real time)."""
    import argparse

    import bench_scale

    args = argparse.Namespace(vehicles=64, duration=1800.0, pace="lockstep")
    # 400 s of wall for 1800 s of drive; the second half grows by 0.01 MB per wall second
    series = [(float(t), [300.0 + (0.01 * (t - 200) if t >= 200 else 0.0)]) for t in range(10, 410, 10)]
    run = {"rss_series": series, "solved": 1, "wall_s": 400.0, "server_peak_rss_mb": [304]}
    line = bench_scale.memory_table(run, args).splitlines()[-1]
    # 0.01 MB/s x 400/1800 x 600 s = 1.33 MB per 10 minutes of the drive
    assert "trend +1.3 MB per 10 minutes of the drive" in line, line
    # a band that breathes (0 / +5 MB in turn) reads +5 MB from two samples, a tenth of it as a trend
    flat = {**run, "rss_series": [(t, [300.0 + (5.0 if k % 2 else 0.0)]) for k, (t, _) in enumerate(series)]}
    assert "last - first +5 MB; trend +0.5 MB" in bench_scale.memory_table(flat, args).splitlines()[-1]
