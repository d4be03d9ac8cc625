"""Receivers without Doppler on the held-out dense city (docs/results.md, "Held-out benchmark,
receivers without Doppler"; docs/fgo.md, "Receivers without Doppler"): the factor graph keeps its
vehicles where the EKF baselines run away, and `pc` is ahead of every baseline. These seeds chose
nothing (HELD_OUT, the benchmark of docs/results.md: every seed, 4 vehicles x 200 s); limits are
the issue's 0.85 where it holds, else the measured values (in the docstrings, printed with -s)
plus a margin for another CPU's last bits.
"""

from __future__ import annotations

import pytest

from coplane.evaluate.benchmark import (
    BASELINES,
    HELD_OUT,
    HELD_OUT_DURATION_S,
    make_recordings,
    pooled_by_environment,
)
from coplane.evaluate.front_ends import FrontEndMemo
from coplane.evaluate.metrics import PooledStats

pytestmark = pytest.mark.slow
SCENARIO = "dense-urban"


@pytest.fixture(scope="module")
def stats(tmp_path_factory: pytest.TempPathFactory) -> dict[str, PooledStats]:
    tmp = tmp_path_factory.mktemp("no-doppler")
    recs = make_recordings(SCENARIO, HELD_OUT[SCENARIO], tmp, 4, HELD_OUT_DURATION_S, doppler=False)
    memo = FrontEndMemo()  # as tests/evaluate/test_benchmark_ordering.py: the same bits, less CPU
    methods = ("pc", "non-cp", *BASELINES)
    out = {m: pooled_by_environment(recs, m, jobs=1, front_ends=memo)[0]["all"] for m in methods}
    for m, s in out.items():
        print(
            f"{SCENARIO} without Doppler, {m}: H RMSE {s.h_rmse_m:.2f} max {s.h_max_m:.1f}, V RMSE {s.v_rmse_m:.2f}"
        )
    return out


def test_the_graph_does_not_run_away(stats: dict[str, PooledStats]) -> None:
    """Largest horizontal errors, measured 2026-12-02 on seeds 1601-1605: pc 50 m, non-cp 103 m
    (the EKF baselines 219 m; with the settings before, the training seeds' pc reached 4 km;
    on the retired seeds 1001-1005 pc 52 m, non-cp 106 m, the EKFs 309-314 m)."""
    assert stats["pc"].h_max_m < 70.0
    assert stats["non-cp"].h_max_m < 140.0
    assert stats["non-cp"].h_rmse_m < 0.85 * stats["non-cp-ekf"].h_rmse_m  # 10.3 against 13.8 m


def test_pc_is_ahead_of_every_baseline(stats: dict[str, PooledStats]) -> None:
    """pc / best baseline (gamp-cp), measured 2026-12-02 on seeds 1601-1605: H 0.80, V 0.61
    (0.80, 0.60 before the height's own sigma, 2026-11-30; 0.79, 0.69 on the retired seeds
    1001-1005)."""
    assert stats["pc"].h_rmse_m <= 0.85 * min(stats[m].h_rmse_m for m in BASELINES)
    assert stats["pc"].v_rmse_m <= 0.8 * min(stats[m].v_rmse_m for m in BASELINES)
