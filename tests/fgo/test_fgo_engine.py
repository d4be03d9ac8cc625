"""FusionEstimator on a synthetic fleet: accuracy per method, outages, membership, solvers, clusters,
determinism, degenerate inputs and ranging interruption.

Margins, not exact numbers; measured values are in the comments (seeded, so they do not drift).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import subprocess
import sys
from collections.abc import Sequence
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as hst
from support.fgo_synthetic import SyntheticFleet, error_stats, make_fleet, run

from coplane.estimation.contract import (
    EpochInput,
    FleetSolution,
    PlaneObs,
    PseudorangeObs,
    RangeObs,
    VehicleEpochInput,
    VelocityObs,
)
from coplane.fgo.config import FgoConfig, Solver
from coplane.fgo.engine import FusionEstimator
from coplane.fgo.links import clock_drift
from coplane.fgo.state import GraphState
from coplane.fgo.window import Window
from coplane.gtime import GpsTime
from coplane.methods import INTERRUPTION_BLOCK, METHODS, MethodSpec, get_method, interrupt_range
from coplane.typing import Vec

SOLVERS: tuple[Solver, ...] = ("lm-window", "isam2-fixed-lag", "batch-fixed-lag")
NLOS: dict[str, Any] = {"nlos_per_vehicle": 1, "nlos_bias": (10.0, 30.0)}


def interrupt_ranges(  # the offline form of interrupt_range, for these tests
    ranges_by_epoch: Sequence[Sequence[RangeObs]],
    rate: float,
    rng_seed: int = 0,
    *,
    block: int = INTERRUPTION_BLOCK,
) -> list[tuple[RangeObs, ...]]:
    """Per-epoch range lists (index = epoch index) with the interrupted ones removed.

    The same decisions as `interrupt_range`, so offline and streaming runs agree.
    """
    interrupt_range(("a", "b"), 0, rate)  # validates the rate
    return [
        tuple(r for r in ranges if not interrupt_range((r.a, r.b), k, rate, rng_seed, block=block))
        for k, ranges in enumerate(ranges_by_epoch)
    ]


@cache
def nlos_fleet(seed: int) -> SyntheticFleet:
    return make_fleet(4, 40, seed=seed, **NLOS)


@cache
def method_runs(seed: int, method: str) -> list[FleetSolution]:
    return run(nlos_fleet(seed), get_method(method).fgo)


def pooled(seeds: Sequence[int], method: str) -> tuple[float, float]:
    """(horizontal, vertical) RMSE over several seeded fleets, first 5 epochs skipped."""
    hs, vs = [], []
    for s in seeds:
        st = error_stats(nlos_fleet(s), method_runs(s, method), skip=5)
        hs.append(st.h_rmse**2 * st.n)
        vs.append(st.v_rmse**2 * st.n)
    n = sum(error_stats(nlos_fleet(s), method_runs(s, method), skip=5).n for s in seeds)
    return math.sqrt(sum(hs) / n), math.sqrt(sum(vs) / n)


SEEDS = (0, 1, 2, 3)


# ---------------------------------------------------------------------------------------------
# (a)-(c) accuracy per method


def test_non_cp_error_is_consistent_with_the_pseudorange_noise() -> None:
    """Clean fleet (sigma 3 m, 14 satellites): the window beats single-epoch SPP and the errors
    agree with the reported covariance (NEES ~ 3 for 3-D; measured h 1.24 m, v 1.63 m, NEES 2.3,
    single-epoch SPP h 2.66 m)."""
    fleet = make_fleet(4, 40, seed=1)
    # the graph's own marginal: white noise here, so no reporting scale (docs/fgo.md)
    sols = run(fleet, dataclasses.replace(get_method("non-cp").fgo, covariance_scale=1.0))
    st = error_stats(fleet, sols, skip=5)
    spp_h = []
    nees = []
    for k, sol in enumerate(sols):
        for vid, est in sol.estimates.items():
            if k < 5:
                continue
            e = est.position_m - fleet.truth[k][vid]
            nees.append(float(e @ np.linalg.solve(est.covariance_m2, e)))
            spp = fleet.epochs[k].vehicles[vid].spp_position
            assert spp is not None
            d = fleet.enu @ (spp - fleet.truth[k][vid])
            spp_h.append(d[0] ** 2 + d[1] ** 2)
    spp_h_rmse = math.sqrt(float(np.mean(spp_h)))
    assert 0.3 < st.h_rmse < 2.0
    assert 0.3 < st.v_rmse < 3.0
    assert st.h_rmse < spp_h_rmse
    assert 1.0 < float(np.mean(nees)) < 6.0
    # the FDE's w-test (1e-3 per test, iterated) may drop a clean satellite now and then
    n_pr = [est.n_pseudoranges for s in sols for est in s.estimates.values()]
    assert all(est.has_gnss_fix for s in sols for est in s.estimates.values())
    assert min(n_pr) >= 12 and sum(14 - n for n in n_pr) <= 0.02 * 14 * len(n_pr)


def test_mci_beats_non_cp_horizontally() -> None:
    """Inter-vehicle ranging (measured over 4 NLOS seeds: non-cp h 5.94 m -> mci h 4.18 m)."""
    h_non, _ = pooled(SEEDS, "non-cp")
    h_mci, _ = pooled(SEEDS, "mci")
    assert h_mci < 0.8 * h_non


def test_pc_beats_mci_in_the_vertical() -> None:
    """Exact planes pin the vertical (measured with the methods' defaults: mci v 1.31 m -> pc v 0.02 m)."""
    _, v_mci = pooled(SEEDS, "mci")
    _, v_pc = pooled(SEEDS, "pc")
    assert v_pc < 0.1 * v_mci


def test_pc_does_not_lose_horizontally_to_mci() -> None:
    """Measured pc h 0.61 m, mci 0.73 m. Without the range warm-up pc was 1.86 m: two vehicles
    4 m apart started from swapped SPP fixes and the range held them there (docs/fgo.md)."""
    h_mci, _ = pooled(SEEDS, "mci")
    h_pc, _ = pooled(SEEDS, "pc")
    assert h_pc < 1.15 * h_mci


def test_pc_without_ranging_still_gains_from_the_fleet_planes() -> None:
    """Range-free CP (measured: non-cp h/v 5.94/10.68 m -> pc-no-ir 5.25/0.09 m)."""
    _, v_non = pooled(SEEDS, "non-cp")
    h_nir, v_nir = pooled(SEEDS, "pc-no-ir")
    h_non, _ = pooled(SEEDS, "non-cp")
    assert v_nir < 0.1 * v_non
    assert h_nir < 1.1 * h_non


# ---------------------------------------------------------------------------------------------
# (d) GNSS outage longer than the window


@pytest.mark.parametrize("solver", SOLVERS)
@pytest.mark.parametrize(("method", "bound", "growth"), [("non-cp", 40.0, 1.3), ("pc", 12.0, 1.15)])
def test_full_gnss_outage_longer_than_the_window_stays_bounded(
    solver: Solver, method: str, bound: float, growth: float
) -> None:
    """v02 loses all GNSS (pseudoranges, Doppler, SPP) for 10 epochs, twice the window: it is
    carried by the motion fallback (+ planes and ranges for pc). Bound for non-cp: the last
    Doppler velocity held for 10 s while the synthetic speed changes by up to 0.63 m/s^2 gives
    <= 31 m plus the error before the outage. The reported 3-D sigma grows by the motion fallback
    (0.5 m/s per second horizontally, 0.2 vertically) and shrinks when GNSS returns; measured with
    the methods' defaults: non-cp 2.2-2.3 -> 3.2-3.3 m (smoothers), pc grows by > 15 %."""
    outage = range(15, 25)
    fleet = make_fleet(4, 32, seed=3, outages={"v02": outage}, **NLOS)
    sols = run(fleet, get_method(method, solver=solver).fgo)
    errs, sig = {}, {}
    for k, sol in enumerate(sols):
        est = sol.estimates["v02"]  # always estimated
        errs[k] = float(np.linalg.norm(est.position_m - fleet.truth[k]["v02"]))
        sig[k] = math.sqrt(float(np.trace(est.covariance_m2)))
        assert est.has_gnss_fix == (k not in outage)
        # outside the outage: 14 minus what the FDE excluded (the vehicle's NLOS satellite)
        assert est.n_pseudoranges == 0 if k in outage else 12 <= est.n_pseudoranges <= 14
    assert max(errs[k] for k in outage) < bound
    assert max(errs.values()) < bound
    assert sig[outage[-1]] > growth * sig[outage[0] - 1]
    assert sig[outage[-1]] > sig[outage[0]]
    assert sig[outage[-1] + 3] < sig[outage[-1]]  # GNSS back: it shrinks again


# ---------------------------------------------------------------------------------------------
# (e) vehicles joining and leaving


@pytest.mark.parametrize("solver", SOLVERS)
def test_vehicles_join_leave_and_return(solver: Solver) -> None:
    """v03 misses 3 epochs (< window: relinked to its last state over the gap), v04 leaves for 12
    (> window: dropped, re-initialised from SPP on return), v05 joins at epoch 8."""
    absent = {"v03": range(10, 13), "v04": range(12, 24), "v05": range(0, 8)}
    fleet = make_fleet(5, 34, seed=4, absent=absent, **NLOS)
    cfg = get_method("pc", solver=solver).fgo
    est = FusionEstimator(cfg)
    for k, epoch in enumerate(fleet.epochs):
        sol = est.step(epoch)
        assert sorted(sol.estimates) == sorted(epoch.vehicles), k
        assert not sol.skipped
        for vid, e in sol.estimates.items():
            assert np.linalg.norm(e.position_m - fleet.truth[k][vid]) < 15.0, (k, vid)
        tracked = est.tracked_vehicles
        if k == 12 + cfg.window_epochs:  # v04 gone for more than the window: dropped
            assert "v04" not in tracked
        if k in range(10, 13):
            assert "v03" in tracked  # still in the window
        if k == 24:
            assert sol.estimates["v04"].n_ranges > 0


# ---------------------------------------------------------------------------------------------
# (f) solvers agree


def test_all_solvers_agree_on_a_clean_case() -> None:
    """No NLOS: LM window, iSAM2 and batch fixed-lag smoothers give similar positions. The window
    and the smoothers differ by design (deleted vs marginalised history). iSAM2 makes one
    Gauss-Newton step per epoch (`isam2_extra_iterations` 0) and relinearises and marginalises on
    every fifth update only (`isam2_cycle_updates`), where the batch smoother does both at every
    epoch: measured RMS position difference to the batch smoother 0.101 m (0.116 m with Huber;
    0.064 / 0.091 m relinearising and marginalising at every update), 0.010 m with one more step
    per epoch; the same h RMSE, 0.40 m."""
    fleet = make_fleet(4, 30, seed=2)
    # plain least squares (the methods default to Huber; the robust case is checked below)
    runs = {s: run(fleet, dataclasses.replace(get_method("pc", solver=s).fgo, robust=None)) for s in SOLVERS}
    stats = {s: error_stats(fleet, r, skip=5) for s, r in runs.items()}
    huber = {s: run(fleet, get_method("pc", solver=s).fgo) for s in ("isam2-fixed-lag", "batch-fixed-lag")}
    d_huber = math.sqrt(
        float(
            np.mean(
                [
                    np.linalg.norm(x.position_m - huber["batch-fixed-lag"][k].estimates[v].position_m) ** 2
                    for k, sol in enumerate(huber["isam2-fixed-lag"])
                    for v, x in sol.estimates.items()
                ]
            )
        )
    )
    # iSAM2 relinearises only where the change is large, so with a Huber kernel (weights depend on
    # the linearisation point) it sits measurably off the batch optimum
    assert d_huber < 0.15

    def rms_diff(a: str, b: str) -> float:
        d = [
            np.linalg.norm(x.position_m - runs[b][k].estimates[v].position_m) ** 2
            for k, sol in enumerate(runs[a])
            for v, x in sol.estimates.items()
        ]
        return math.sqrt(float(np.mean(d)))

    assert rms_diff("isam2-fixed-lag", "batch-fixed-lag") < 0.12
    # ... and one more Gauss-Newton step per epoch brings it to the batch optimum
    more = dataclasses.replace(get_method("pc").fgo, robust=None, isam2_extra_iterations=1)
    runs["isam2-2-steps"] = run(fleet, more)
    assert rms_diff("isam2-2-steps", "batch-fixed-lag") < 0.02
    assert rms_diff("lm-window", "isam2-fixed-lag") < 0.5
    assert rms_diff("lm-window", "batch-fixed-lag") < 0.5
    hs = {s: st.h_rmse for s, st in stats.items()}
    # with the methods' tight Doppler links the marginalising smoothers keep more history than the
    # 5-epoch window (measured h RMSE: lm 0.60 m, iSAM2 0.40 m, batch 0.40 m)
    assert (
        hs["isam2-fixed-lag"] < 1.1 * hs["batch-fixed-lag"]
        and hs["batch-fixed-lag"] < 1.1 * hs["isam2-fixed-lag"]
    )
    assert hs["lm-window"] < 1.6 * min(hs.values())
    assert all(st.v_rmse < 0.1 for st in stats.values())


# ---------------------------------------------------------------------------------------------
# (g) clusters


@pytest.mark.parametrize("solver", SOLVERS)
def test_cluster_split_equals_the_joint_solve(solver: Solver) -> None:
    """Two groups 3 km apart (ranges only within a group): solving each cluster alone gives the
    same estimates as one graph of everything. iSAM2: identical positions (measured difference 0,
    covariances 4e-14 m^2). LM: identical to the LM stopping precision; a pseudorange error is a
    difference of ~2e7 m numbers, so the cost is resolved to ~1e-8 and the optimum to ~0.1 mm
    (measured 1.1e-4 m lm-window). The batch smoother then linearises its marginal priors at those
    slightly different points: measured 2.4e-3 m, covariances 0.13 %."""
    fleet = make_fleet(4, 16, seed=5, group_size=2, group_spacing=3000.0, **NLOS)
    cfg = dataclasses.replace(
        get_method("pc", solver=solver).fgo,
        lm_relative_error_tol=1e-12,
        lm_absolute_error_tol=1e-12,
        range_warmup_epochs=0,  # cluster mechanics from the first epoch
        covariance_scale=1.0,  # tolerances below are for the graph's own marginals
    )
    if solver == "isam2-fixed-lag":
        # each smoother relinearises on its own cycle (`isam2_cycle_updates`), which its own
        # history sets (a rebuild, a converging vehicle): split and joint smoothers then relinearise
        # at different epochs by design (measured up to 0.42 m on this NLOS fleet with Huber), so
        # the structural claim is checked with a relinearisation at every update
        cfg = dataclasses.replace(cfg, isam2_cycle_updates=1)
    if solver == "batch-fixed-lag":
        # its marginal priors are relinearised at the slightly different LM points; a Huber kernel
        # (the methods' default) amplifies that to ~1 cm, so the structural claim is checked on
        # plain least squares here (iSAM2 and the LM window are checked with Huber as configured)
        cfg = dataclasses.replace(cfg, robust=None)
    split = run(fleet, cfg)
    joint = run(fleet, dataclasses.replace(cfg, split_clusters=False))
    assert all(s.n_clusters == 2 for s in split)
    assert all(s.n_clusters == 1 for s in joint)
    atol, cov_rtol = {
        "isam2-fixed-lag": (1e-9, 1e-9),
        "lm-window": (1e-3, 1e-3),
        # LM to convergence inside each smoother: the split and joint problems stop at slightly
        # different points (measured up to 22 mm with the methods' 0.1 m/s Doppler links, and
        # 1.4e-3 m^2: 0.3 % of the largest variance)
        "batch-fixed-lag": (3e-2, 1e-2),
    }[solver]
    for a, b in zip(split, joint, strict=True):
        assert sorted(a.estimates) == sorted(b.estimates)
        for vid in a.estimates:
            np.testing.assert_allclose(
                a.estimates[vid].position_m, b.estimates[vid].position_m, atol=atol, rtol=0
            )
            # off-diagonal terms are compared on the scale of the variances, not their own
            cov_b = b.estimates[vid].covariance_m2
            np.testing.assert_allclose(
                a.estimates[vid].covariance_m2,
                cov_b,
                rtol=cov_rtol,
                atol=cov_rtol * float(np.max(np.diag(cov_b))),
            )


def test_with_the_cycle_split_and_joint_clusters_differ_by_their_relinearisation_only() -> None:
    """The same fleet as above with iSAM2's default cycle (`isam2_cycle_updates` 5): each smoother
    relinearises on its own cycle, so split and joint clusters no longer agree exactly, but only
    by what a relinearisation later or sooner moves (docs/fgo.md, "Once per cycle": measured up to
    0.42 m on one axis on this NLOS fleet with Huber)."""
    fleet = make_fleet(4, 16, seed=5, group_size=2, group_spacing=3000.0, **NLOS)
    cfg = dataclasses.replace(
        get_method("pc", solver="isam2-fixed-lag").fgo, range_warmup_epochs=0, covariance_scale=1.0
    )
    assert cfg.isam2_cycle_updates == 5
    split = run(fleet, cfg)
    joint = run(fleet, dataclasses.replace(cfg, split_clusters=False))
    worst = max(
        float(np.max(np.abs(a.estimates[v].position_m - b.estimates[v].position_m)))
        for a, b in zip(split, joint, strict=True)
        for v in a.estimates
    )
    assert 0.0 < worst < 0.5


@pytest.mark.parametrize("solver", SOLVERS)
def test_clusters_merge_and_split_when_ranges_come_and_go(solver: Solver) -> None:
    """Two pairs starting 300 m apart; an injected v01-v03 range at epochs 8-10, and the two roads
    cross at epochs 13-17 (ranges between all four): the clusters merge (the smoothers are rebuilt
    into one from the window + anchors) and split again once the cross ranges leave the window
    (rebuilt into two). Estimates stay as good as one graph that is never split or rebuilt
    (measured 3-D RMSE split / joint: lm-window, iSAM2 and batch within 3 %)."""
    fleet = make_fleet(4, 24, seed=15, group_size=2, group_spacing=300.0, max_range=100.0, **NLOS)
    rng = np.random.default_rng(0)
    epochs = []
    for k, e in enumerate(fleet.epochs):
        extra: tuple[RangeObs, ...] = ()
        if 8 <= k <= 10:
            d = float(np.linalg.norm(fleet.truth[k]["v01"] - fleet.truth[k]["v03"]))
            extra = (RangeObs("v01", "v03", d + rng.normal(0.0, 0.3), 0.3),)
        epochs.append(dataclasses.replace(e, ranges=e.ranges + extra))
    cfg = dataclasses.replace(get_method("pc", solver=solver).fgo, range_warmup_epochs=0)
    sols = run(fleet, cfg, epochs)
    joint = run(fleet, dataclasses.replace(cfg, split_clusters=False), epochs)  # never rebuilt
    w = cfg.window_epochs
    cross = [any({r.a, r.b} not in ({"v01", "v02"}, {"v03", "v04"}) for r in e.ranges) for e in epochs]
    expected = [1 if any(cross[max(0, k - w + 1) : k + 1]) else 2 for k in range(len(epochs))]
    assert expected.count(1) >= 10 and expected[-1] == 2 and expected[8] == 1 and expected[7] == 2
    assert [s.n_clusters for s in sols] == expected
    errors: dict[str, list[float]] = {"split": [], "joint": []}
    for k, (sol, one) in enumerate(zip(sols, joint, strict=True)):
        assert sorted(sol.estimates) == ["v01", "v02", "v03", "v04"]
        for vid, est in sol.estimates.items():
            errors["split"].append(float(np.linalg.norm(est.position_m - fleet.truth[k][vid])))
            errors["joint"].append(float(np.linalg.norm(one.estimates[vid].position_m - fleet.truth[k][vid])))
    rms = {kind: math.sqrt(float(np.mean(np.square(e)))) for kind, e in errors.items()}
    assert max(errors["split"]) < 10.0
    assert rms["split"] < 1.15 * rms["joint"]  # the rebuilds lose next to nothing


def test_window_clusters_stay_within_their_bound() -> None:
    """Eight vehicles that all range to each other, the window's clusters bounded to 4 vehicles:
    the ranges that would join two clusters beyond it are left out and counted, every epoch has
    two clusters of four, and every vehicle is still solved. Within the bound (the default 32)
    every range is kept: the same bits as no bound at all."""
    fleet = make_fleet(8, 12, seed=7, group_size=8, max_range=500.0)
    cfg = dataclasses.replace(get_method("pc").fgo, range_warmup_epochs=0)
    sols = run(fleet, dataclasses.replace(cfg, window_cluster_max=4))
    assert all(s.n_clusters == 2 and len(s.estimates) == 8 for s in sols)
    assert all(s.rejected.get("range_cluster_bound", 0) > 0 for s in sols)
    assert _fingerprint(run(fleet, cfg)) == _fingerprint(
        run(fleet, dataclasses.replace(cfg, window_cluster_max=0))
    )
    with pytest.raises(ValueError, match="window_cluster_max"):
        dataclasses.replace(cfg, window_cluster_max=-1)


def test_ranges_merge_clusters() -> None:
    fleet = make_fleet(4, 6, seed=5, group_size=2, group_spacing=3000.0)
    sols = run(fleet, get_method("mci").fgo)
    assert sols[-1].n_clusters == 2
    sols = run(fleet, get_method("non-cp").fgo)
    assert sols[-1].n_clusters == 4


# ---------------------------------------------------------------------------------------------
# (h) determinism


def _fingerprint(sols: Sequence[FleetSolution]) -> list[object]:
    out: list[object] = []
    for s in sols:
        for vid in sorted(s.estimates):
            e = s.estimates[vid]
            out.append(
                (
                    vid,
                    e.position_m.tobytes().hex(),
                    e.covariance_m2.tobytes().hex(),
                    sorted(e.clocks_s.items()),
                )
            )
        out.append((sorted(s.factor_counts.items()), s.iterations, repr(s.error_after)))
    return out


@pytest.mark.parametrize("solver", SOLVERS)
def test_same_inputs_give_bitwise_identical_outputs(solver: Solver) -> None:
    fleet = make_fleet(5, 20, seed=6, absent={"v05": range(5, 12)}, **NLOS)
    cfg = get_method("pc", solver=solver).fgo
    assert _fingerprint(run(fleet, cfg)) == _fingerprint(run(fleet, cfg))


_DETERMINISM_SCRIPT = """
import hashlib, json, sys
sys.path[:0] = [{tests!r}, {here!r}]
from support.fgo_synthetic import make_fleet
from test_fgo_engine import _fingerprint, run
from coplane.methods import get_method
fleet = make_fleet(4, 12, seed=7, nlos_per_vehicle=1)
out = {{s: hashlib.sha256(repr(_fingerprint(run(fleet, get_method("pc", solver=s).fgo))).encode()).hexdigest()
       for s in ("lm-window", "isam2-fixed-lag")}}
print(json.dumps(out))
"""


def test_determinism_across_processes_and_hash_seeds() -> None:
    here = Path(__file__).resolve().parent
    code = _DETERMINISM_SCRIPT.format(tests=str(here.parent), here=str(here))
    outs = []
    for seed in ("1", "2"):
        env = {**os.environ, "PYTHONHASHSEED": seed}
        res = subprocess.run(
            [sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120
        )
        assert res.returncode == 0, res.stderr
        outs.append(json.loads(res.stdout.strip().splitlines()[-1]))
    assert outs[0] == outs[1]


# ---------------------------------------------------------------------------------------------
# (i) fewer than 4 satellites, indeterminate and degenerate problems


@pytest.mark.parametrize("solver", SOLVERS)
def test_fewer_than_four_satellites(solver: Solver) -> None:
    """v01 keeps only 2-3 satellites (and no Doppler) for 6 epochs: still estimated, no fix."""
    limits = {("v01", k): (2 if k % 2 else 3) for k in range(10, 16)}
    fleet = make_fleet(4, 22, seed=8, sat_limit=limits, **NLOS)
    for method in ("non-cp", "pc"):
        sols = run(fleet, get_method(method, solver=solver).fgo)
        for k, sol in enumerate(sols):
            est = sol.estimates["v01"]
            assert est.has_gnss_fix == (k not in range(10, 16))
            assert np.linalg.norm(est.position_m - fleet.truth[k]["v01"]) < 20.0


@pytest.mark.parametrize("solver", SOLVERS)
def test_undetermined_epochs_are_dead_reckoned(solver: Solver) -> None:
    """Opt-in: a tracked vehicle with fewer pseudoranges than a fix needs (4, 3 with a plane) uses
    none of them and each is counted; by default they are kept (docs/fgo.md)."""
    limits = {("v01", k): (2 if k % 2 else 3) for k in range(10, 16)}
    fleet = make_fleet(4, 22, seed=8, sat_limit=limits, **NLOS)
    for method, used_with_three in (("non-cp", 0), ("pc", 3)):
        cfg = get_method(method, solver=solver).fgo
        assert cfg is not None and not cfg.drop_undetermined_pseudoranges
        dropping = dataclasses.replace(cfg, drop_undetermined_pseudoranges=True)
        for drop, sols in ((False, run(fleet, cfg)), (True, run(fleet, dropping))):
            for k in range(10, 16):
                est, n = sols[k].estimates["v01"], limits[("v01", k)]
                dropped = sols[k].rejected.get("undetermined_pseudorange", 0)
                if not drop:
                    assert (est.n_pseudoranges, dropped) == (n, 0)
                elif n == 3 and used_with_three:
                    assert (est.n_pseudoranges, dropped) == (3, 0)
                else:
                    assert (est.n_pseudoranges, dropped) == (0, n)


def _standing(epoch: EpochInput, vid: str, claim_speed: float = 0.0) -> EpochInput:
    """`epoch` with `vid`'s velocity replaced by the front end's standstill claim (zero velocity;
    `claim_speed` > 0 makes it a contradictory claim, as a hostile sender might send)."""
    v = epoch.vehicles[vid]
    still = VelocityObs(np.array([claim_speed, 0.0, 0.0]), 0.1, standstill=True)
    return dataclasses.replace(
        epoch, vehicles={**epoch.vehicles, vid: dataclasses.replace(v, velocity=still)}
    )


def test_standing_undetermined_epochs_are_dead_reckoned_by_default() -> None:
    """By default only a detected standstill dead-reckons an undetermined epoch (docs/fgo.md,
    "Few satellites on a real receiver"); a standstill claim with a speed is not one."""
    limits = {("v01", k): 3 for k in range(10, 16)}
    fleet = make_fleet(4, 18, seed=8, sat_limit=limits, **NLOS)
    cfg = get_method("non-cp").fgo
    assert cfg is not None and cfg.standstill_dead_reckoning
    for claim_speed, dropped_each in ((0.0, 3), (0.5, 0)):
        epochs = [
            _standing(e, "v01", claim_speed) if k in range(10, 16) else e for k, e in enumerate(fleet.epochs)
        ]
        est = FusionEstimator(cfg)
        for k, e in enumerate(epochs):
            sol = est.step(e)
            if k in range(10, 16):
                assert sol.rejected.get("undetermined_pseudorange", 0) == dropped_each
                assert sol.rejected.get("standstill", 0) == (1 if claim_speed else 0)  # counted
                assert sol.estimates["v01"].n_pseudoranges == 3 - dropped_each
    off = dataclasses.replace(cfg, standstill_dead_reckoning=False)
    est = FusionEstimator(off)
    for k, e in enumerate(fleet.epochs):
        sol = est.step(_standing(e, "v01") if k in range(10, 16) else e)
        assert sol.rejected.get("undetermined_pseudorange", 0) == 0


def test_clock_drift_without_doppler() -> None:
    """Without a Doppler drift the clock steps by zero with the loose sigma; with
    `clock_drift_carry` by the last measured drift (its sigma growing by `clock_drift_wander` per
    second when set)."""
    cfg = FgoConfig()
    state = GraphState(window=Window(cfg.window_epochs))
    t0 = GpsTime(2300, 1000.0)
    assert clock_drift("v01", None, None, t0, state, cfg) == (0.0, cfg.clock_drift_sigma)
    assert clock_drift("v01", 220.0, 218.0, t0, state, cfg) == (219.0, 0.0)
    state.drift_seen["v01"] = (220.0, t0)
    assert clock_drift("v01", None, None, t0 + 10.0, state, cfg) == (0.0, cfg.clock_drift_sigma)
    carry = dataclasses.replace(cfg, clock_drift_carry=True)
    assert clock_drift("v01", None, None, t0 + 10.0, state, carry) == (220.0, cfg.clock_drift_sigma)
    tight = dataclasses.replace(carry, clock_drift_wander=0.2)
    mean, sigma = clock_drift("v01", None, None, t0 + 10.0, state, tight)
    assert mean == 220.0 and sigma == pytest.approx(2.0)
    assert clock_drift("v01", None, None, t0 + 1e6, state, tight)[1] == cfg.clock_drift_sigma
    with pytest.raises(ValueError, match="clock_drift_wander"):
        FgoConfig(clock_drift_wander=-1.0)


def _first_epoch(fleet: SyntheticFleet, changes: dict[str, dict[str, object]]) -> EpochInput:
    e = fleet.epochs[0]
    vehicles = {vid: dataclasses.replace(v, **changes.get(vid, {})) for vid, v in e.vehicles.items()}  # type: ignore[arg-type]
    return dataclasses.replace(e, vehicles=vehicles)


@pytest.mark.parametrize("solver", SOLVERS)
def test_indeterminate_new_vehicle_is_skipped_not_raised(solver: Solver) -> None:
    fleet = make_fleet(4, 2, seed=9)
    e0 = fleet.epochs[0]
    two_sats = e0.vehicles["v01"].pseudoranges[:2]
    epoch = _first_epoch(fleet, {"v01": {"pseudoranges": two_sats, "velocity": None, "plane": None}})
    epoch = dataclasses.replace(epoch, ranges=())
    sol = FusionEstimator(get_method("pc", solver=solver).fgo).step(epoch)
    assert "v01" not in sol.estimates
    assert "not enough measurements" in sol.skipped["v01"]
    assert sorted(sol.estimates) == ["v02", "v03", "v04"]


@pytest.mark.parametrize("solver", SOLVERS)
def test_new_vehicle_determined_through_ranges_and_plane(solver: Solver) -> None:
    """2 satellites (1 constraint) + plane (1) + ranges to 3 solved vehicles: determined."""
    fleet = make_fleet(4, 2, seed=9)
    e0 = fleet.epochs[0]
    gps = tuple(p for p in e0.vehicles["v01"].pseudoranges if p.system == "G")[:2]
    epoch = _first_epoch(fleet, {"v01": {"pseudoranges": gps}})
    # ranges from the first epoch (the default warm-up holds short ranges back for 5 epochs)
    sol = FusionEstimator(
        dataclasses.replace(get_method("pc", solver=solver).fgo, range_warmup_epochs=0)
    ).step(epoch)
    assert "v01" in sol.estimates
    assert not sol.estimates["v01"].has_gnss_fix
    assert sol.estimates["v01"].n_ranges == 3
    assert np.linalg.norm(sol.estimates["v01"].position_m - fleet.truth[0]["v01"]) < 10.0
    # without the ranges it is not
    sol = FusionEstimator(get_method("pc-no-ir", solver=solver).fgo).step(epoch)
    assert "v01" in sol.skipped


@pytest.mark.parametrize("solver", SOLVERS)
def test_degenerate_geometry_does_not_crash(solver: Solver) -> None:
    """Four 'satellites' at the same place: counted as enough, singular in fact. GTSAM fails, the
    estimator retries with priors (or drops the epoch): it must not raise."""
    fleet = make_fleet(4, 3, seed=10)
    out = []
    est = FusionEstimator(get_method("non-cp", solver=solver).fgo)
    for k, e in enumerate(fleet.epochs):
        v = e.vehicles["v02"]
        same = v.pseudoranges[0]
        prs = tuple(dataclasses.replace(same, sat=f"G{40 + i}") for i in range(5))
        changes = {"v02": {"pseudoranges": prs}} if k == 0 else {}
        epoch = dataclasses.replace(
            e, vehicles={vid: dataclasses.replace(x, **changes.get(vid, {})) for vid, x in e.vehicles.items()}
        )  # type: ignore[arg-type]
        out.append(est.step(epoch))
    assert "v01" in out[0].estimates
    assert "v02" in out[0].estimates or "v02" in out[0].skipped
    assert "v02" in out[-1].estimates


@pytest.mark.parametrize("solver", SOLVERS)
def test_receiver_clock_jump_restarts_the_clock(solver: Solver) -> None:
    """A 1 ms receiver clock jump (3e5 m) must not be forced through the clock random walk."""
    fleet = make_fleet(3, 16, seed=14, clock_jumps={"v01": 8})
    sols = run(fleet, get_method("pc", solver=solver).fgo)
    assert sols[8].rejected == {"clock_link": 1}  # v01's receiver clock (BeiDou's offset goes on)
    assert all(not (s.rejected.keys() - {"range_warmup"}) for k, s in enumerate(sols) if k != 8)
    for k, sol in enumerate(sols):
        assert np.linalg.norm(sol.estimates["v01"].position_m - fleet.truth[k]["v01"]) < 10.0
    jump = sols[8].estimates["v01"].clocks_s["G"] - sols[7].estimates["v01"].clocks_s["G"]
    assert jump == pytest.approx(1e-3, abs=1e-6)


def test_bad_inputs_are_rejected_and_counted() -> None:
    fleet = make_fleet(3, 4, seed=11)
    est = FusionEstimator(get_method("pc").fgo)
    est.step(fleet.epochs[0])
    e1 = fleet.epochs[1]
    v1 = e1.vehicles["v01"]
    bad_prs = (
        dataclasses.replace(v1.pseudoranges[0], rho_m=float("nan")),
        dataclasses.replace(v1.pseudoranges[1], sat="X05"),
        dataclasses.replace(v1.pseudoranges[2], sigma_m=-1.0),
        dataclasses.replace(v1.pseudoranges[3], sat_pos_m=np.array([1.0, 2.0, 3.0])),
        v1.pseudoranges[4],
        v1.pseudoranges[4],  # duplicate satellite
        *v1.pseudoranges[5:],
    )
    vehicles = dict(e1.vehicles)
    vehicles["v01"] = dataclasses.replace(
        v1,
        pseudoranges=bad_prs,
        plane=PlaneObs(np.array([0.0, 0.0, 2.0]), 1.0, 0.1),  # not a unit normal
        velocity=VelocityObs(np.array([np.inf, 0.0, 0.0]), 0.6),
        spp_position=np.array([1.0, 1.0, 1.0]),  # at the Earth's centre
    )
    vehicles["v02"] = dataclasses.replace(e1.vehicles["v02"], vehicle_id="someone-else")
    d13 = float(np.linalg.norm(fleet.truth[1]["v01"] - fleet.truth[1]["v03"]))
    ranges = (
        RangeObs("v01", "v01", 5.0, 0.3),
        RangeObs("v01", "v03", float("nan"), 0.3),
        RangeObs("v01", "v03", d13, 0.0),  # sigma <= 0: config.range_sigma is used
        RangeObs("v03", "v01", d13 + 50.0, 0.3),  # the same pair again: rejected, not used
        RangeObs("v01", "v02", 10.0, 0.3),  # v02 is skipped: ignored, not an error
    )
    sol = est.step(EpochInput(e1.time, vehicles, ranges))
    assert sol.rejected == {"pseudorange": 5, "plane": 1, "velocity": 1, "spp": 1, "range": 3, "vehicle": 1}
    assert "v02" in sol.skipped and "match" in sol.skipped["v02"]
    v01 = sol.estimates["v01"]  # tracked: carried on by the valid measurements
    assert v01.n_pseudoranges == len(v1.pseudoranges) - 4
    assert v01.n_ranges == 1 and not v01.plane_used
    assert np.linalg.norm(v01.position_m - fleet.truth[1]["v01"]) < 10.0
    # the same epoch again: rejected as a whole, state unchanged
    again = est.step(EpochInput(e1.time, vehicles, ranges))
    assert again.estimates == {} and again.rejected == {"epoch": 1}
    assert sorted(est.step(fleet.epochs[2]).estimates) == ["v01", "v02", "v03"]


def test_empty_epochs_and_unknown_vehicles_in_ranges() -> None:
    fleet = make_fleet(2, 3, seed=12)
    est = FusionEstimator()
    sol = est.step(EpochInput(fleet.epochs[0].time, {}, (RangeObs("a", "b", 10.0, 0.3),)))
    assert sol.estimates == {} and sol.n_clusters == 0
    sol = est.step(dataclasses.replace(fleet.epochs[1], ranges=(RangeObs("v01", "ghost", 10.0, 0.3),)))
    assert sorted(sol.estimates) == ["v01", "v02"]
    assert sol.estimates["v01"].n_ranges == 0


def test_pseudorange_obs_model_matches_the_estimate() -> None:
    """One static receiver, noise-free pseudoranges built with the inputs.py model: the estimate
    is the truth to millimetres (catches a Sagnac or clock-unit slip end to end)."""
    fleet = make_fleet(1, 1, seed=13, pr_sigma=1e-6)
    sol = FusionEstimator(get_method("non-cp").fgo).step(fleet.epochs[0])
    assert np.linalg.norm(sol.estimates["v01"].position_m - fleet.truth[0]["v01"]) < 0.01


# ---------------------------------------------------------------------------------------------
# methods


def test_methods_registry() -> None:
    assert list(METHODS) == [
        "non-cp",
        "mci",
        "pc",
        "pc-no-ir",
        "pc-no-ir-no-fe",
        "pc-self",
        "pc-map",
        "pc-self-map",
        "non-cp-ekf",
        "dd-cp",
        "gamp-cp",
    ]
    assert [m for m, s in METHODS.items() if s.plane_map] == ["pc-map", "pc-self-map"]
    assert all(METHODS[m].factory is not None for m in ("non-cp-ekf", "dd-cp", "gamp-cp"))
    pc = get_method("pc")
    assert pc.fgo.use_ranging and pc.fgo.use_planes and pc.planes == "fleet" and pc.plane_fault_exclusion
    assert not get_method("non-cp").fgo.use_planes and not get_method("non-cp").fgo.use_ranging
    assert get_method("mci").fgo.use_ranging and not get_method("mci").fgo.use_planes
    assert not get_method("pc-no-ir-no-fe").plane_fault_exclusion
    assert get_method("pc-self").planes == "self" and not get_method("pc-self").fgo.use_ranging
    spec = get_method("pc", solver="batch-fixed-lag", window_epochs=8)
    assert isinstance(spec, MethodSpec)
    assert spec.fgo.solver == "batch-fixed-lag" and spec.fgo.window_epochs == 8
    assert METHODS["pc"].fgo.solver == "isam2-fixed-lag"  # the registry is not mutated
    # every method trusts the Doppler velocity equally (docs/fgo.md, round of 2026-11-25)
    sigmas = {get_method(m).velocity_sigma_mps for m in ("non-cp", "pc", "non-cp-ekf", "dd-cp", "gamp-cp")}
    assert sigmas == {0.1}
    with pytest.raises(ValueError, match="valid methods: non-cp, mci, pc"):
        get_method("PC-aided")
    with pytest.raises(ValueError, match="unknown solver"):
        FgoConfig(solver="ekf")  # type: ignore[arg-type]
    with pytest.raises(ValueError):
        FgoConfig(window_epochs=0)


# ---------------------------------------------------------------------------------------------
# (j) ranging interruption (paper Sec. 5.3)


def _ranges_fleet(n_epochs: int) -> list[tuple[RangeObs, ...]]:
    pairs = [("v01", "v02"), ("v01", "v03"), ("v02", "v03"), ("v03", "v04")]
    return [tuple(RangeObs(a, b, 10.0, 0.3) for a, b in pairs) for _ in range(n_epochs)]


def _per_pair(kept: Sequence[Sequence[RangeObs]]) -> dict[tuple[str, str], int]:
    out: dict[tuple[str, str], int] = {}
    for ranges in kept:
        for r in ranges:
            out[(r.a, r.b)] = out.get((r.a, r.b), 0) + 1
    return out


def test_interruption_rates_zero_one_and_exact_share_per_pair() -> None:
    ranges = _ranges_fleet(200)
    assert interrupt_ranges(ranges, 0.0, 1) == [tuple(r) for r in ranges]
    assert all(not k for k in interrupt_ranges(ranges, 1.0, 1))
    kept = interrupt_ranges(ranges, 0.4, 1)
    assert _per_pair(kept) == {p: 120 for p in _per_pair(ranges)}  # exactly 40 % removed per pair
    assert interrupt_ranges(ranges, 0.4, 1) == kept  # deterministic
    assert interrupt_ranges(ranges, 0.4, 2) != kept  # the seed matters
    # the removed epochs differ between pairs (independent per pair)
    drops = {
        p: [k for k, rs in enumerate(kept) if not any((r.a, r.b) == p for r in rs)] for p in _per_pair(ranges)
    }
    assert len({tuple(d) for d in drops.values()}) == len(drops)
    # streaming decisions are the same, whatever the order of the pair
    for k in range(200):
        for a, b in (("v01", "v02"), ("v03", "v04")):
            assert interrupt_range((a, b), k, 0.4, 1) == interrupt_range((b, a), k, 0.4, 1)
            assert interrupt_range((a, b), k, 0.4, 1) == (not any((r.a, r.b) == (a, b) for r in kept[k]))
    with pytest.raises(ValueError):
        interrupt_range(("a", "b"), 0, 1.5)
    # a partial block: close to the rate
    share = 1 - sum(_per_pair(interrupt_ranges(_ranges_fleet(150), 0.2, 3)).values()) / (150 * 4)
    assert abs(share - 0.2) < 0.05


@settings(max_examples=40, deadline=None)
@given(rate=hst.floats(0.0, 1.0), seed=hst.integers(0, 2**31 - 1), offset=hst.integers(0, 10))
def test_interruption_removes_exactly_the_rate_per_pair_and_block(
    rate: float, seed: int, offset: int
) -> None:
    """Property: over any full block of 100 epochs each pair loses exactly round(rate * 100)."""
    first = offset * 100
    ranges = [(RangeObs("a", "b", 5.0, 0.3), RangeObs("b", "c", 6.0, 0.3))] * (first + 100)
    kept = interrupt_ranges(ranges, rate, seed)[first:]
    for pair in (("a", "b"), ("b", "c")):
        n_kept = sum(1 for rs in kept for r in rs if (r.a, r.b) == pair)
        assert 100 - n_kept == round(rate * 100)


def test_mci_degrades_with_interruption_more_than_pc() -> None:
    """Paper Figs. 11-12 in miniature: removing all ranges hurts mci, pc keeps the vertical."""
    fleet = nlos_fleet(0)
    cut = [
        dataclasses.replace(e, ranges=r)
        for e, r in zip(fleet.epochs, interrupt_ranges([e.ranges for e in fleet.epochs], 1.0, 0), strict=True)
    ]
    mci_full = error_stats(fleet, method_runs(0, "mci"), skip=5)
    mci_cut = error_stats(fleet, run(fleet, get_method("mci").fgo, cut), skip=5)
    pc_cut = error_stats(fleet, run(fleet, get_method("pc").fgo, cut), skip=5)
    assert mci_cut.h_rmse > mci_full.h_rmse
    assert pc_cut.v_rmse < 0.2 * mci_cut.v_rmse


def test_synthetic_generator_is_deterministic() -> None:
    a, b = make_fleet(3, 5, seed=21, **NLOS), make_fleet(3, 5, seed=21, **NLOS)
    for ea, eb in zip(a.epochs, b.epochs, strict=True):
        for vid in ea.vehicles:
            pa, pb = ea.vehicles[vid].pseudoranges, eb.vehicles[vid].pseudoranges
            assert [p.rho_m for p in pa] == [p.rho_m for p in pb]
        assert ea.ranges == eb.ranges
    assert isinstance(a.epochs[0].vehicles["v01"], VehicleEpochInput)
    assert isinstance(a.epochs[0].vehicles["v01"].pseudoranges[0], PseudorangeObs)


def test_innovation_gate_removes_nlos_pseudoranges_before_the_graph() -> None:
    """gate_k: pseudoranges far from the predicted position are dropped (counted), which the Huber
    kernel alone cannot fully do; the clean satellites are kept. Off by default (docs/fgo.md)."""
    fleet = make_fleet(4, 40, seed=11, nlos_per_vehicle=2, nlos_bias=(20.0, 40.0))
    base = dataclasses.replace(get_method("non-cp").fgo, fde_k=None)  # the gate alone
    plain = run(fleet, base)
    gated = run(fleet, dataclasses.replace(base, gate_k=3.5))
    e_plain = error_stats(fleet, plain, skip=5)
    e_gated = error_stats(fleet, gated, skip=5)
    n_gated = sum(s.rejected.get("gated_pseudorange", 0) for s in gated)
    print(
        f"h RMSE plain {e_plain.h_rmse:.2f} gated {e_gated.h_rmse:.2f}; v {e_plain.v_rmse:.2f} -> {e_gated.v_rmse:.2f}; gated {n_gated}"
    )
    assert n_gated > 0
    assert sum(s.rejected.get("gated_pseudorange", 0) for s in plain) == 0
    assert e_gated.h_rmse < e_plain.h_rmse and e_gated.v_rmse < e_plain.v_rmse
    # at most the NLOS satellites (2 per vehicle per epoch) and a few clean ones are removed
    assert n_gated <= 4 * 40 * 2 * 1.2


def _moved(fleet: SyntheticFleet, vid: str, offset_m: Vec, from_epoch: int) -> list[EpochInput]:
    """The fleet's epochs with `vid`'s pseudoranges (and SPP) from `from_epoch` on measured as if
    its antenna stood `offset_m` (ECEF) away from where the track says, all consistent."""
    out = []
    for k, ep in enumerate(fleet.epochs):
        v = ep.vehicles.get(vid)
        if k < from_epoch or v is None:
            out.append(ep)
            continue
        p = fleet.truth[k][vid]
        prs = tuple(
            dataclasses.replace(
                pr,
                rho_m=pr.rho_m
                + np.linalg.norm(pr.sat_pos_m - p - offset_m)
                - np.linalg.norm(pr.sat_pos_m - p),
            )
            for pr in v.pseudoranges
        )
        spp = None if v.spp_position is None else v.spp_position + offset_m
        moved = dataclasses.replace(v, pseudoranges=prs, spp_position=spp)
        out.append(dataclasses.replace(ep, vehicles={**ep.vehicles, vid: moved}))
    return out


def test_a_diverged_track_restarts_only_after_epochs_without_redundancy() -> None:
    """`fde_restart_chi2` (docs/fgo.md, "A diverged track comes back"): from epoch 20 every
    pseudorange says the vehicle stands 150 m from its track. After epochs with only 4 satellites
    in the window the track starts anew there (counted `track_restart`); after full-sky epochs the
    prediction is rejected but the track keeps its links, as in the simulator's canyons, where such
    a clean-looking fit was the wrong one: the epoch is dead-reckoned (`fde_snapshot_dead_reckon`),
    and only after three such epochs, the prediction having coasted, does the track start anew."""
    offset = np.array([150.0, 0.0, 0.0])
    cfg = get_method("non-cp").fgo
    assert cfg is not None and cfg.fde_restart_chi2 is not None
    for weak, restarts in ((True, True), (False, False)):
        limits = {("v01", k): 4 for k in range(16, 20)} if weak else {}
        fleet = make_fleet(1, 26, seed=3, sat_limit=limits)
        offset_ecef = offset @ fleet.enu  # E, N, U -> ECEF
        sols = run(fleet, cfg, _moved(fleet, "v01", offset_ecef, 20))
        assert sols[20].rejected.get("fde_prediction_rejected", 0) == 1
        assert (sols[20].rejected.get("track_restart", 0) == 1) == restarts
        err = np.linalg.norm(sols[20].estimates["v01"].position_m - fleet.truth[20]["v01"] - offset_ecef)
        assert (err < 10.0) == restarts, err
        if not weak:
            assert [sols[k].rejected.get("fde_dead_reckoned", 0) for k in range(20, 24)] == [1, 1, 1, 0]
            assert sols[23].rejected.get("track_restart", 0) == 1
            err = np.linalg.norm(sols[23].estimates["v01"].position_m - fleet.truth[23]["v01"] - offset_ecef)
            assert err < 10.0, err


@pytest.mark.parametrize("method", ["non-cp", "non-cp-ekf", "dd-cp"])
def test_each_estimate_names_the_satellites_it_left_out(method: str) -> None:
    """`VehicleEstimate.excluded_satellites`: exactly the node's pseudoranges the estimator did
    not use (so a user sees which, not only how many), sorted; with two NLOS satellites per
    vehicle biased 20-40 m, most of what the FDE or the EKF's gate leaves out is NLOS."""
    fleet = make_fleet(4, 30, seed=11, nlos_per_vehicle=2, nlos_bias=(20.0, 40.0))
    spec = get_method(method)
    est = spec.build_estimator()
    sols = [est.step(e) for e in fleet.epochs]
    n_out = n_nlos = 0
    for ep, sol in zip(fleet.epochs, sols, strict=True):
        for vid, est in sol.estimates.items():
            given = [p.sat for p in ep.vehicles[vid].pseudoranges]
            assert list(est.excluded_satellites) == sorted(est.excluded_satellites)
            assert set(est.excluded_satellites) <= set(given)
            assert len(est.excluded_satellites) == len(given) - est.n_pseudoranges
            n_out += len(est.excluded_satellites)
            n_nlos += len(set(est.excluded_satellites) & fleet.nlos[vid])
    assert n_out > 0 and n_nlos >= 0.8 * n_out, (n_out, n_nlos)
