"""`coplane eval` on several cores: worker processes own some vehicles' steps (evaluate.vehicle_workers).

Whatever the number of processes, and with GNSS front ends an earlier run computed
(evaluate.front_ends), a run must give the same bits; a failing worker must stop the run with its
traceback instead of hanging or dropping vehicles.
"""

from __future__ import annotations

import gc
from pathlib import Path

import numpy as np
import pytest

from coplane.evaluate.evaluation import evaluate
from coplane.evaluate.front_ends import FrontEndMemo
from coplane.evaluate.runner import MethodRun, run_method
from coplane.evaluate.vehicle_workers import VehicleWorkers, default_jobs, split_vehicles
from coplane.gnss.epoch_solver import EpochSolverOptions
from coplane.gnss.spp import SppOptions
from coplane.recording.reader import Recording, open_recording
from coplane.sim.generate import simulate
from coplane.steps import VehicleStep

pytestmark = pytest.mark.skipif(not VehicleWorkers.available(), reason="needs fork")


@pytest.fixture(scope="module")
def rec30(tmp_path_factory: pytest.TempPathFactory) -> Recording:
    path = simulate("urban-loop", tmp_path_factory.mktemp("rec30") / "rec", vehicles=5, duration_s=30, seed=3)
    return open_recording(Path(path))


def _same(a: MethodRun, b: MethodRun) -> None:
    assert a.positions.keys() == b.positions.keys()
    for v in a.positions:
        assert a.positions[v].keys() == b.positions[v].keys()
        for t, p in a.positions[v].items():
            assert np.array_equal(p, b.positions[v][t]), (v, t)
            assert np.array_equal(a.covariances[v][t], b.covariances[v][t])
        assert a.planes[v] == b.planes[v] and a.ranges_used[v] == b.ranges_used[v]


@pytest.mark.parametrize("method", ["pc", "gamp-cp"])
@pytest.mark.parametrize("dgnss", [None, False], ids=["dgnss", "standalone"])
def test_any_number_of_processes_gives_the_same_bits(
    rec30: Recording, method: str, dgnss: bool | None
) -> None:
    """Standalone too, where the broadcast delays and the covariance's atmosphere term are
    computed. (The delays cache that once handed one vehicle's delays to another, docs/gnss-models.md,
    did not collide here; tests/gnss/test_atmosphere.py provokes that bug.)"""
    alone = run_method(rec30, method, jobs=1, dgnss=dgnss)
    assert sum(len(p) for p in alone.positions.values()) > 100
    for jobs in (2, 3, 6):  # 1, 2 and 5 workers (one per vehicle)
        _same(alone, run_method(rec30, method, jobs=jobs, dgnss=dgnss))


@pytest.mark.parametrize("dgnss", [None, False], ids=["dgnss", "standalone"])
def test_front_ends_of_an_earlier_run_give_the_same_bits(rec30: Recording, dgnss: bool | None) -> None:
    """A memo filled by one method serves the next ones, in one process and with workers."""
    memo = FrontEndMemo()
    first = run_method(rec30, "non-cp", jobs=1, dgnss=dgnss)
    _same(first, run_method(rec30, "non-cp", jobs=2, dgnss=dgnss, front_ends=memo))
    assert memo.n_epochs == sum(len(p) for p in first.positions.values())  # every vehicle-epoch
    for method, jobs in (("pc", 1), ("gamp-cp", 2)):
        alone = run_method(rec30, method, jobs=1, dgnss=dgnss)
        _same(alone, run_method(rec30, method, jobs=jobs, dgnss=dgnss, front_ends=memo))


def test_eval_in_one_process_shares_the_front_ends_with_the_same_bits(rec30: Recording) -> None:
    """`coplane eval --jobs 1` keeps a memo across its methods (evaluate.evaluation)."""
    ev = evaluate(rec30, ["non-cp", "pc"], jobs=1)
    _same(ev.runs[1], run_method(rec30, "pc", jobs=2))


def test_front_ends_are_remembered_per_setup_and_within_the_bound(rec30: Recording) -> None:
    """Other solver options or no DGNSS are another front end; past the bound nothing is kept."""
    memo = FrontEndMemo()
    run_method(rec30, "non-cp", jobs=1, front_ends=memo)
    kept = memo.n_epochs
    masked = EpochSolverOptions(spp=SppOptions(elevation_mask_deg=25.0))
    alone = run_method(rec30, "non-cp", jobs=1, front_end=masked)
    _same(alone, run_method(rec30, "non-cp", jobs=1, front_end=masked, front_ends=memo))
    assert memo.n_epochs == 2 * kept
    standalone = run_method(rec30, "non-cp", jobs=1, dgnss=False)
    _same(standalone, run_method(rec30, "non-cp", jobs=1, dgnss=False, front_ends=memo))
    assert memo.n_epochs == 3 * kept
    small = FrontEndMemo(max_epochs=kept // 2)
    _same(alone, run_method(rec30, "non-cp", jobs=1, front_end=masked, front_ends=small))
    assert small.n_epochs <= kept // 2


def test_base_corrections_are_computed_once_for_every_run(
    rec30: Recording, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The base's corrections of an epoch are the same for every method: a memo computes each
    epoch's once, whatever number of runs ask for it, and its runs keep the same bits."""
    import coplane.gnss.epoch_solver as epoch_solver

    calls: list[object] = []
    compute = epoch_solver.base_corrections
    monkeypatch.setattr(epoch_solver, "base_corrections", lambda *a: calls.append(a) or compute(*a))
    memo = FrontEndMemo()
    assert memo.base(rec30, True) is memo.base(rec30, True) is not memo.base(rec30, False)
    runs = [run_method(rec30, m, jobs=1, front_ends=memo) for m in ("non-cp", "mci", "non-cp")]
    epochs = len({t for p in runs[0].positions.values() for t in p})
    assert 0 < len(calls) <= epochs  # once per epoch with a base epoch, not once per run
    assert memo.base(rec30, True).remembered_epochs == len(calls)
    small = FrontEndMemo(max_epochs=epochs // 2)
    monkeypatch.undo()
    _same(runs[0], run_method(rec30, "non-cp", jobs=1, front_ends=small))
    assert small.base(rec30, True).remembered_epochs == epochs // 2  # the bound holds
    _same(runs[2], run_method(rec30, "non-cp", jobs=1))
    _same(runs[1], run_method(rec30, "mci", jobs=1))


def test_a_recording_that_is_gone_frees_its_share_of_the_bound(rec30: Recording) -> None:
    memo = FrontEndMemo()
    other = open_recording(rec30.manifest.root)
    run_method(other, "non-cp", jobs=1, front_ends=memo)
    assert memo.n_epochs > 0
    del other
    gc.collect()
    assert memo.n_epochs == 0


def test_worker_failure_stops_the_run_with_its_traceback(
    rec30: Recording, monkeypatch: pytest.MonkeyPatch
) -> None:
    real = VehicleStep.process

    def broken(self: VehicleStep, *args: object, **kwargs: object) -> object:
        if self.vehicle_id == "u2":  # a worker's vehicle (u1 stays in this process)
            raise ValueError("injected failure in u2's step")
        return real(self, *args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(VehicleStep, "process", broken)
    with pytest.raises(RuntimeError, match=r"(?s)vehicle worker \d+ failed.*injected failure in u2"):
        run_method(rec30, "mci", jobs=2)


def test_vehicles_are_dealt_to_groups() -> None:
    assert split_vehicles(["a", "b", "c", "d", "e"], 2) == [["a", "c", "e"], ["b", "d"]]
    assert split_vehicles(["a", "b"], 4) == [["a"], ["b"]]
    assert split_vehicles(["a", "b"], 1) == [["a", "b"]]
    assert 1 <= default_jobs(1) <= 2 and 1 <= default_jobs(64) <= 65  # one per vehicle + the fusion


def test_jobs_below_one_is_a_clear_error(rec30: Recording) -> None:
    with pytest.raises(ValueError, match="jobs must be >= 1, got 0"):
        run_method(rec30, "non-cp", jobs=0)
