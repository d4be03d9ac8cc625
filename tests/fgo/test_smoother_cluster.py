"""`SmootherCluster`: what a fixed-lag smoother reports, and how a diverged one is caught.

GTSAM's IncrementalFixedLagSmoother never puts iSAM2's error in its result, so the estimator does
not ask iSAM2 to evaluate it (CPU for nothing) and reports NaN; divergence
is caught on the estimates instead, and the cluster is rebuilt from the window.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import gtsam
import numpy as np
import pytest
from support.fgo_synthetic import make_fleet, run

from coplane.fgo import factors, keys, smoother, window
from coplane.fgo.recipes import Recipe
from coplane.gnss.constants import C
from coplane.gtime import GpsTime
from coplane.methods import get_method


def test_isam2_reports_no_graph_error_and_batch_does() -> None:
    fleet = make_fleet(2, 6, seed=3)
    isam2 = run(fleet, get_method("pc", solver="isam2-fixed-lag").fgo)
    batch = run(fleet, get_method("pc", solver="batch-fixed-lag").fgo)
    assert all(math.isnan(s.error_after) for s in isam2)
    assert all(math.isfinite(s.error_after) and s.error_after >= 0.0 for s in batch)


class _Diverged:
    """An iSAM2 smoother stand-in whose estimate has run away to NaN."""

    def __init__(self, real: Any) -> None:
        self.real = real

    def update(self, *args: Any) -> Any:
        return self.real.update(*args)

    def __getattr__(self, name: str) -> Any:  # the lag, the iSAM2: the real smoother's
        return getattr(self.real, name)

    def calculateEstimate(self, keys: Any = None) -> gtsam.Values:
        v = gtsam.Values()
        for k in keys:
            v.insert(k, np.full(3, np.nan))
        return v


def test_a_non_finite_estimate_raises() -> None:
    cfg = get_method("pc", solver="isam2-fixed-lag").fgo
    assert cfg is not None
    sm = smoother.SmootherCluster(cfg, ["a"])
    sm.smoother = _Diverged(sm.smoother)  # type: ignore[assignment]
    pk = keys.position_key(0, 0)  # a kind iSAM2 has a relinearisation threshold for
    prior = Recipe(factors.position_prior, pk, np.zeros(3), np.eye(3))
    init = gtsam.Values()
    init.insert(pk, np.ones(3))
    blk = window.StateBlock(
        vehicle_id="a",
        step=0,
        time=GpsTime(2100, 0.0),
        pos_key=pk,
        clock_keys={},
        init_pos=np.ones(3),
        init_clocks={},
        recipes=[prior],
        counts={},
        links=[],
        n_pseudoranges=0,
        plane_used=False,
        velocity=None,
        clock_drift_mps=None,
        has_fix=True,
    )
    with pytest.raises(RuntimeError, match="non-finite position"):
        sm.update([blk], [], [], init, {pk: 0.0}, [], 0, [pk])


def test_the_estimator_rebuilds_a_diverged_smoother(monkeypatch: pytest.MonkeyPatch) -> None:
    """One diverged update costs a rebuild from the window, not the vehicles' estimates."""
    fleet = make_fleet(3, 8, seed=4)
    cfg = get_method("pc", solver="isam2-fixed-lag").fgo
    clean = run(fleet, cfg)
    real_update = smoother.SmootherCluster.update
    calls: list[tuple[int, bool]] = []  # (smoother, raised) per update
    seen: dict[int, int] = {}

    def update(self: smoother.SmootherCluster, *a: Any, **kw: Any) -> Any:
        sid = seen.setdefault(id(self), len(seen))
        diverge = sid == 0 and sum(1 for s, _ in calls if s == 0) == 2  # the first one's third update
        real = self.smoother
        if diverge:
            self.smoother = _Diverged(real)  # type: ignore[assignment]
        try:
            out = real_update(self, *a, **kw)
        except RuntimeError:
            calls.append((sid, True))
            raise
        finally:
            self.smoother = real
        calls.append((sid, False))
        return out

    monkeypatch.setattr(smoother.SmootherCluster, "update", update)
    sols = run(fleet, cfg)
    assert calls[2] == (0, True)
    assert calls[3][0] > 0  # the same cluster, solved again by a smoother built from the window
    for a, b in zip(clean, sols, strict=True):
        assert set(a.estimates) == set(b.estimates)
        assert not b.skipped
        for vid, e in b.estimates.items():
            assert np.isfinite(e.position_m).all()
            assert np.linalg.norm(e.position_m - a.estimates[vid].position_m) < 1.0


def _huber_snapshot(clock_guess_error_m: float) -> tuple[window.StateBlock, gtsam.Values]:
    """One receiver, 9 satellites, one of them 40 m long (NLOS), Huber kernel; the clock's first
    guess is off by `clock_guess_error_m` metres, as an SPP clock is against the fused one."""
    rng = np.random.default_rng(7)
    receiver = np.array([-2414266.9, 5386768.8, 2407460.0])
    up = receiver / np.linalg.norm(receiver)
    sats, rho = [], []
    clock_s = 1e-4
    for i in range(9):
        d = rng.normal(size=3)
        d = d - (d @ up) * up + (0.3 + 0.7 * rng.random()) * np.linalg.norm(d) * up
        sat = receiver + 2.2e7 * d / np.linalg.norm(d)
        sats.append(sat)
        rho.append(
            np.linalg.norm(sat - receiver) + C * clock_s + rng.normal(0, 1.0) + (40.0 if i == 0 else 0.0)
        )
    pk, ck = keys.position_key(0, 0), keys.clock_key(0, 0, "G")
    prs = Recipe(
        factors.pseudorange_factors,
        pk,
        [ck] * 9,
        rho,
        np.array(sats),
        [0.0] * 9,
        [2.0] * 9,
        receiver,
        "huber",
        1.345,
    )
    init = gtsam.Values()
    init_pos = receiver + np.array([3.0, -2.0, 4.0])
    init.insert(pk, init_pos)
    init.insert(ck, clock_s + clock_guess_error_m / C)
    blk = window.StateBlock(
        vehicle_id="a", step=0, time=GpsTime(2100, 0.0), pos_key=pk, clock_keys={"G": ck},
        init_pos=init_pos, init_clocks={ck: clock_s}, recipes=[prs], counts={}, links=[],
        n_pseudoranges=9, plane_used=False, velocity=None, clock_drift_mps=None, has_fix=True,
    )  # fmt: skip
    return blk, init


@pytest.mark.parametrize("clock_guess_error_m", [0.0, 5.0, -20.0])
def test_isam2_reaches_the_graphs_optimum_whatever_the_clocks_first_guess(clock_guess_error_m: float) -> None:
    """Clocks are in seconds: iSAM2 must relinearise them on a threshold in seconds, or the Huber
    weights stay at the clock's first guess and the smoother stops away from the optimum."""
    cfg = get_method("pc", solver="isam2-fixed-lag").fgo
    assert cfg is not None
    blk, init = _huber_snapshot(clock_guess_error_m)
    params = gtsam.GaussNewtonParams()
    params.setMaxIterations(100)
    params.setRelativeErrorTol(1e-12)
    params.setAbsoluteErrorTol(1e-12)
    best = gtsam.GaussNewtonOptimizer(blk.graph(), init, params).optimize().atPoint3(blk.pos_key)
    sm = smoother.SmootherCluster(cfg, ["a"])
    res = sm.update([blk], [], [], init, {k: 0.0 for k in blk.keys}, [], 0, blk.keys, converge=True)
    assert np.linalg.norm(res.values.atPoint3(blk.pos_key) - best) < 0.02


def test_every_kind_of_key_has_a_relinearisation_threshold_in_its_unit() -> None:
    """GTSAM reads a key's threshold from the map without a default: a missing kind is undefined."""
    th = keys.relinearize_thresholds(0.01)
    assert th.size() == 1 + len(keys.CLOCK_CHR) + len(keys.BIAS_CHR)


@pytest.mark.parametrize("cycle", [1, 3, 5])
def test_isam2_marginalises_and_relinearises_once_per_cycle(
    cycle: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    """`isam2_cycle_updates`: states leave the smoother on one update per cycle only, so it holds
    between the window and the window plus a cycle less one epoch, and iSAM2 relinearises on those
    same updates (both re-eliminate its whole tree). 1 is every update, as GTSAM does."""
    fleet = make_fleet(2, 24, seed=3)
    cfg = dataclasses.replace(get_method("pc", solver="isam2-fixed-lag").fgo, isam2_cycle_updates=cycle)
    held: list[tuple[int, int, int, int]] = []  # (update index, epochs held before, after, relinearised)
    real = smoother.SmootherCluster._update

    def spy(self: smoother.SmootherCluster, *a: Any) -> Any:
        before = len(set(self.smoother.timestamps().values()))
        out = real(self, *a)
        index = self._updates  # iSAM2's count, this update included
        relin = self.smoother.getISAM2Result().getVariablesRelinearized()
        held.append((index, before, len(set(self.smoother.timestamps().values())), relin))
        return out

    monkeypatch.setattr(smoother.SmootherCluster, "_update", spy)
    run(fleet, cfg)
    assert len(held) > 3 * cycle
    for index, before, after, relin in held:
        assert after <= cfg.window_epochs + cycle - 1
        if index % cycle:
            assert relin == 0
            if before:  # (a new smoother takes the whole window at once)
                assert after == before + 1  # nothing left: the new epoch only came in
    # the smoother did fill beyond the window between cycles (or held exactly it, with 1)
    assert max(after for *_, after, _ in held) == cfg.window_epochs + cycle - 1


def test_isam2_cycle_updates_must_be_a_positive_integer() -> None:
    base = get_method("pc").fgo
    for bad in (0, -1, 2.5):
        with pytest.raises(ValueError, match="isam2_cycle_updates"):
            dataclasses.replace(base, isam2_cycle_updates=bad)


def test_between_cycles_isam2_re_eliminates_only_part_of_its_tree(monkeypatch: pytest.MonkeyPatch) -> None:
    """Why the cycle saves CPU (docs/fgo.md, "Once per cycle"): the update that marginalises and
    relinearises re-eliminates at least every variable the smoother keeps, while an update in
    between re-eliminates fewer than it holds (the newest epochs). Once a smoother has been through
    its first cycle; 4 vehicles linked by ranges, the methods' iSAM2 defaults."""
    cfg = get_method("pc", solver="isam2-fixed-lag").fgo
    assert cfg is not None and cfg.isam2_cycle_updates > 1
    seen: list[tuple[bool, int, int]] = []  # (on the cycle, variables re-eliminated, variables held)
    real = smoother.SmootherCluster._update

    def spy(self: smoother.SmootherCluster, *a: Any) -> Any:
        out = real(self, *a)
        on_cycle = self._updates % self.cfg.isam2_cycle_updates == 0
        reeliminated = self.smoother.getISAM2Result().getVariablesReeliminated()
        seen.append((on_cycle, reeliminated, self.smoother.getLinearizationPoint().size()))
        return out

    monkeypatch.setattr(smoother.SmootherCluster, "_update", spy)
    run(make_fleet(4, 30, seed=2), cfg)
    first = next(i for i, (on, _, _) in enumerate(seen) if on)
    after = seen[first + 1 :]
    assert sum(on for on, _, _ in after) >= 3 and sum(not on for on, _, _ in after) >= 10
    for on, reeliminated, held in after:
        if on:
            assert reeliminated >= held
        else:
            assert reeliminated < held


def _crossing_pairs() -> tuple[Any, list[Any]]:
    """Two pairs 300 m apart whose roads cross at epochs 13-17 (ranges between all four): their
    clusters merge, then split again once the cross ranges leave the window."""
    fleet = make_fleet(4, 24, seed=15, group_size=2, group_spacing=300.0, max_range=100.0)
    return fleet, list(fleet.epochs)


@pytest.mark.parametrize("keep", [True, False])
def test_a_split_cluster_is_rebuilt_or_keeps_its_smoother_for_its_largest_part(
    monkeypatch: pytest.MonkeyPatch, keep: bool
) -> None:
    """On a split both parts are built from the window (the default), or with
    `isam2_keep_on_split` the first of the equal parts goes on with the merged cluster's smoother
    and only the other is built. Either way the positions stay as good as one graph that is never
    split."""
    from coplane.fgo.engine import FusionEstimator

    fleet, epochs = _crossing_pairs()
    base = dataclasses.replace(get_method("pc", solver="isam2-fixed-lag").fgo, range_warmup_epochs=0)
    cfg = dataclasses.replace(base, isam2_keep_on_split=keep)
    built: list[list[tuple[str, ...]]] = []  # per epoch: the vehicles of each smoother built
    run_one = smoother.LocalSmoothers.run_one

    def counted(self: smoother.LocalSmoothers, task: smoother.SmootherTask) -> Any:
        if task.create:
            built[-1].append(tuple(task.vehicles))
        return run_one(self, task)

    monkeypatch.setattr(smoother.LocalSmoothers, "run_one", counted)
    est = FusionEstimator(cfg)
    sols = []
    for e in epochs:
        built.append([])
        sols.append(est.step(e))
    clusters = [s.n_clusters for s in sols]
    split = next(k for k in range(1, len(clusters)) if clusters[k - 1] == 1 and clusters[k] == 2)
    assert built[split] == ([("v03", "v04")] if keep else [("v01", "v02"), ("v03", "v04")])
    assert all(not b for b in built[split + 1 :])  # both parts then go on with their smoothers
    joint = run(fleet, dataclasses.replace(base, split_clusters=False), epochs)  # never rebuilt
    err = {
        name: [
            float(np.linalg.norm(e.position_m - fleet.truth[k][v]))
            for k, s in enumerate(sols_)
            for v, e in s.estimates.items()
        ]
        for name, sols_ in (("split", sols), ("joint", joint))
    }
    rms = {name: math.sqrt(float(np.mean(np.square(e)))) for name, e in err.items()}
    assert len(err["split"]) == len(err["joint"]) == 4 * len(epochs)
    assert rms["split"] < 1.15 * rms["joint"]


def test_a_kept_smoother_that_fails_on_the_split_is_rebuilt(monkeypatch: pytest.MonkeyPatch) -> None:
    """With `isam2_keep_on_split`, the part that keeps the smoother has its update fail on the
    split epoch, where the other part sends nothing (it stays in the window without a new state):
    the failed smoother is dropped for every vehicle it held, so the keeper is rebuilt in the same
    epoch, the other part in the next, and no task goes to a smoother that is gone."""
    from coplane.fgo.engine import FusionEstimator

    fleet, epochs = _crossing_pairs()
    cfg = dataclasses.replace(
        get_method("pc", solver="isam2-fixed-lag").fgo, range_warmup_epochs=0, isam2_keep_on_split=True
    )
    clusters = [s.n_clusters for s in run(fleet, cfg, epochs)]
    split = next(k for k in range(1, len(clusters)) if clusters[k - 1] == 1 and clusters[k] == 2)
    quiet = {"v03", "v04"}
    e = epochs[split]
    epochs[split] = dataclasses.replace(
        e,
        vehicles={v: x for v, x in e.vehicles.items() if v not in quiet},
        ranges=tuple(r for r in e.ranges if not {r.a, r.b} & quiet),
    )
    update = smoother.SmootherCluster.update
    step = [0]
    failed: list[set[str]] = []

    def failing(
        self: smoother.SmootherCluster, blocks: Any, ranges: Any, priors: Any, *a: Any, **kw: Any
    ) -> Any:
        if step[0] == split and not priors:
            failed.append(set(self.vehicles))
            raise RuntimeError("injected failure")
        return update(self, blocks, ranges, priors, *a, **kw)

    monkeypatch.setattr(smoother.SmootherCluster, "update", failing)
    built: list[tuple[int, tuple[str, ...]]] = []
    run_one = smoother.LocalSmoothers.run_one

    def counted(self: smoother.LocalSmoothers, task: smoother.SmootherTask) -> Any:
        if task.create:
            built.append((step[0], tuple(task.vehicles)))
        return run_one(self, task)

    monkeypatch.setattr(smoother.LocalSmoothers, "run_one", counted)
    est = FusionEstimator(cfg)
    for k, ep in enumerate(epochs):
        step[0] = k
        sol = est.step(ep)
        assert sorted(sol.estimates) == (["v01", "v02"] if k == split else ["v01", "v02", "v03", "v04"])
        assert not sol.skipped
    assert failed == [{"v01", "v02", "v03", "v04"}]  # the merged cluster's smoother, kept by v01-v02
    assert [b for b in built if b[0] >= split] == [(split, ("v01", "v02")), (split + 1, ("v03", "v04"))]
