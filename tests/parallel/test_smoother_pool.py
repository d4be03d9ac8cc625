"""Clusters solved on several processes (`coplane.parallel.SmootherPool`, `--cluster_workers`).

The pool must give the sequential estimates bit for bit, survive a worker that dies, and leave no
process behind.
"""

from __future__ import annotations

import os
import pickle
import signal
import subprocess
import sys
import time
from pathlib import Path

import gtsam
import numpy as np
import pytest
from support.e2e_fleet import running
from support.fgo_synthetic import SyntheticFleet, make_fleet

from coplane.estimation.contract import FleetSolution
from coplane.fgo.engine import FusionEstimator
from coplane.fgo.factors import position_prior
from coplane.fgo.keys import clock_key, is_position_key, position_key
from coplane.fgo.recipes import Recipe, from_wire, to_wire
from coplane.fgo.smoother import SmootherTask
from coplane.fgo.window import StateBlock, build_graph, graph_recipes
from coplane.gtime import GpsTime
from coplane.methods.registry import get_method
from coplane.parallel import smoother_pool as P


def _fleet() -> SyntheticFleet:
    """Three groups of four on their own roads (three clusters), one vehicle absent for a while
    (its cluster splits and merges again: rebuilt smoothers) and one with a GNSS outage."""
    return make_fleet(12, 14, seed=3, group_size=4, absent={"v02": range(4, 7)}, outages={"v07": range(5, 9)})


def _solve(
    fleet: SyntheticFleet, workers: int, kill_at: int | None = None, tasks: list[int] | None = None
) -> list[FleetSolution]:
    cfg = get_method("pc").fgo
    assert cfg is not None and cfg.solver != "lm-window"
    est = FusionEstimator(cfg, smoothers=P.smoothers_for(cfg, workers))
    try:
        out = []
        for i, epoch in enumerate(fleet.epochs):
            if i == kill_at:
                pool = est._smoothers
                assert isinstance(pool, P.SmootherPool)
                os.kill(pool._procs[1].pid, signal.SIGKILL)
                pool._procs[1].join(5.0)
            out.append(est.step(epoch))
        if kill_at is not None:
            assert est.workers == (workers, 1)  # what the server's diagnostics report
        if tasks is not None and isinstance(est._smoothers, P.SmootherPool):
            tasks += est._smoothers.tasks
            pool = est._smoothers  # where its time went: each process's solves, this one's waits
            assert len(pool.busy_s) == workers and all(b > 0 for b in pool.busy_s) and pool.wait_s >= 0
        return out
    finally:
        est.close()


def test_two_workers_give_the_sequential_estimates_bit_for_bit() -> None:
    fleet = _fleet()
    seq = _solve(fleet, 1)
    tasks: list[int] = []
    par = _solve(fleet, 2, tasks=tasks)
    assert min(tasks) > 10  # both processes solved clusters
    assert max(s.n_clusters for s in seq) >= 3
    for a, b in zip(seq, par, strict=True):
        assert sorted(a.estimates) == sorted(b.estimates)
        assert a.skipped == b.skipped and a.rejected == b.rejected
        for vid, ea in a.estimates.items():
            eb = b.estimates[vid]
            assert np.array_equal(ea.position_m, eb.position_m), (a.time, vid)
            assert np.array_equal(ea.covariance_m2, eb.covariance_m2, equal_nan=True), (a.time, vid)
            assert ea.clocks_s == eb.clocks_s


def test_a_window_ships_as_recipes_that_build_its_graph_factor_for_factor() -> None:
    """What a child builds from the recipes (`graph_recipes`, sent through pickle) is the graph
    the server's own process solves (`build_graph`): the same factors in the same order, with the
    same errors. An estimator that ships nothing keeps no recipe arguments."""
    fleet = _fleet()
    cfg = get_method("pc").fgo
    assert cfg is not None
    local = FusionEstimator(cfg)
    shipping = FusionEstimator(cfg)
    shipping._settle = False  # as with a pool, without starting processes
    for epoch in fleet.epochs[:8]:
        local.step(epoch)
        shipping.step(epoch)
    blocks = [b for hist in shipping._state.window.by_vehicle.values() for b in hist]
    ranges = [r for rec in shipping._state.window.steps for r in rec.ranges]
    prior = Recipe(position_prior, blocks[0].pos_key, np.ones(3), np.eye(3))
    oldest = shipping._state.step - cfg.window_epochs + 2  # a link to a state that left is dropped
    here = build_graph(blocks, ranges, [prior], oldest)
    wire = pickle.loads(pickle.dumps(to_wire(graph_recipes(blocks, ranges, [prior], oldest))))
    there = from_wire(wire)
    values = shipping._state.values
    assert there.size() == here.size() > 100
    for i in range(here.size()):
        assert there.at(i).keys() == here.at(i).keys()
        assert there.at(i).error(values) == here.at(i).error(values)
    assert all(b.recipes for b in blocks)
    assert all(not b.recipes for hist in local._state.window.by_vehicle.values() for b in hist)
    assert all(
        ln.args == () for hist in local._state.window.by_vehicle.values() for b in hist for ln in b.links
    )


def test_a_dead_worker_costs_its_clusters_a_rebuild_not_the_estimator() -> None:
    fleet = _fleet()
    seq = _solve(fleet, 1)
    par = _solve(fleet, 2, kill_at=6)
    for a, b in zip(seq, par, strict=True):
        assert sorted(a.estimates) == sorted(b.estimates)
        assert not set(b.skipped) - set(a.skipped)
        for vid, ea in a.estimates.items():
            d = np.linalg.norm(b.estimates[vid].position_m - ea.position_m)
            assert d < 1.0, (a.time, vid, d)  # rebuilt from the window: the same graph, re-solved


def test_close_stops_the_worker_processes() -> None:
    cfg = get_method("pc").fgo
    est = FusionEstimator(cfg, smoothers=P.smoothers_for(cfg, 3))
    pool = est._smoothers
    assert isinstance(pool, P.SmootherPool)
    procs = pool._procs[1:]
    assert all(p.is_alive() for p in procs)
    est.close()
    assert not any(p.is_alive() for p in procs)


def test_no_pool_where_one_process_is_all_there_is_to_use() -> None:
    """One worker, a filter (no factor graph) or lm-window (no smoothers): no processes start."""
    assert P.smoothers_for(get_method("pc", solver="lm-window").fgo, 4) is None
    assert P.smoothers_for(get_method("non-cp-ekf").fgo, 4) is None
    assert P.smoothers_for(get_method("pc").fgo, 1) is None
    with pytest.raises(ValueError, match="workers"):
        P.smoothers_for(get_method("pc").fgo, 0)
    assert FusionEstimator(get_method("pc").fgo).workers == (1, 0)


def test_values_cross_processes_exactly() -> None:
    """GTSAM serialises Point3 values but not doubles: the clocks go as Python floats."""
    rng = np.random.default_rng(0)
    v = gtsam.Values()
    for i in range(5):
        v.insert(position_key(i, 7), rng.normal(size=3) * 6e6)
        v.insert(clock_key(i, 7, "G"), float(rng.normal() * 1e-3))
    back = P.unpack_values(P.pack_values(v))
    assert sorted(back.keys()) == sorted(v.keys())
    for key in v.keys():  # noqa: SIM118 (gtsam.Values has keys(), no iteration)
        assert is_position_key(key) == (gtsam.Symbol(key).chr() == ord("p"))
        if is_position_key(key):
            assert np.array_equal(back.atPoint3(key), v.atPoint3(key))
        else:
            assert back.atDouble(key) == v.atDouble(key)


def test_a_workers_error_keeps_its_class_name() -> None:
    """A skipped reason names GTSAM's exception the same whichever process raised it."""
    exc = P.remote_error("IndeterminantLinearSystemException", "near variable p7")
    assert isinstance(exc, RuntimeError)
    assert f"{type(exc).__name__}: {exc}" == "IndeterminantLinearSystemException: near variable p7"


_PARENT = """
import sys, time
from coplane.fgo.engine import FusionEstimator
from coplane.methods.registry import get_method
from coplane.parallel import smoothers_for
if __name__ == "__main__":
    cfg = get_method("pc").fgo
    est = FusionEstimator(cfg, smoothers=smoothers_for(cfg, 2))
    est._smoothers.wait_ready()
    print(est._smoothers._procs[1].pid, flush=True)
    time.sleep(60)
"""


def test_a_worker_ends_when_its_estimator_is_killed(tmp_path: Path) -> None:
    """kill -9 of the server leaves no solver behind: the child reads end-of-file and returns."""
    script = tmp_path / "parent.py"
    script.write_text(_PARENT)
    parent = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, text=True)
    try:
        assert parent.stdout is not None
        child = int(parent.stdout.readline())
        parent.kill()
        parent.wait(10)
        deadline = time.monotonic() + 10
        while running(child) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not running(child)
    finally:
        parent.kill()


def _prior_task(slot: int, create: bool, step: int) -> SmootherTask:
    """A one-vehicle task: a prior on one position (enough for a smoother to solve)."""
    pk = position_key(0, step)
    prior = Recipe(position_prior, pk, np.ones(3), np.eye(3))
    init = gtsam.Values()
    init.insert(pk, np.zeros(3))
    blk = StateBlock(
        vehicle_id="a", step=step, time=GpsTime(2100, float(step)), pos_key=pk, clock_keys={},
        init_pos=np.zeros(3), init_clocks={}, recipes=[prior], counts={}, links=[], n_pseudoranges=0,
        plane_used=False, velocity=None, clock_drift_mps=None, has_fix=True,
    )  # fmt: skip
    return SmootherTask(slot, create, ["a"], [blk], [], [], init, {pk: float(step)}, [pk], 0, [pk], False)


def test_a_smoother_lost_with_its_worker_fails_its_tasks_every_time() -> None:
    """A child's smoothers go with it: later tasks for them fail (their clusters are rebuilt)
    instead of raising in the estimator."""
    cfg = get_method("pc").fgo
    pool = P.SmootherPool(cfg, 2)
    try:
        pool.wait_ready()
        pool._cost = [1.0, 1e-9]  # the child looks fastest: the new smoother goes there
        first = pool.run([_prior_task(7, True, 0)])[0]
        assert not isinstance(first, Exception)
        assert np.allclose(first.values.atPoint3(position_key(0, 0)), 1.0)
        assert pool.tasks == [0, 1]
        os.kill(pool._procs[1].pid, signal.SIGKILL)
        pool._procs[1].join(5.0)
        for step in (1, 2):
            out = pool.run([_prior_task(7, False, step)])[0]
            assert isinstance(out, RuntimeError)
        again = pool.run([_prior_task(8, True, 3)])[0]  # a rebuild goes to the process left
        assert not isinstance(again, Exception) and pool.tasks[0] == 1 and pool.dead == {1}
    finally:
        pool.close()


def test_the_gtsam_wheel_has_no_tbb_so_its_own_threading_is_not_there() -> None:
    """docs/scale.md chose processes partly because GTSAM's own threading (TBB) is absent from the
    installed wheel: a wheel that bundles TBB would reopen that choice."""
    libs = Path(gtsam.__file__).resolve().parent.parent / "gtsam.libs"
    assert libs.is_dir(), libs
    names = [p.name for p in libs.iterdir()]
    assert any(n.startswith("libgtsam") for n in names), names
    assert not [n for n in names if "tbb" in n.lower()], names
