"""Resuming the factor graph from a vehicle's last state (`FusionEstimator.seed`)."""

from __future__ import annotations

import dataclasses

import numpy as np
from support.fgo_synthetic import make_fleet

from coplane.estimation.contract import EpochInput, VehicleSeed, seed_estimator
from coplane.fgo.config import FgoConfig
from coplane.fgo.engine import FusionEstimator


def _no_gnss(e: EpochInput, vid: str) -> EpochInput:
    v = dataclasses.replace(e.vehicles[vid], pseudoranges=(), spp_position=None)
    return dataclasses.replace(e, vehicles={**e.vehicles, vid: v})


def test_seeded_estimator_continues_a_track_a_fresh_one_cannot() -> None:
    fleet = make_fleet(n_vehicles=3, n_epochs=12, seed=4)
    cfg = FgoConfig()
    before = FusionEstimator(cfg)
    sols = [before.step(e) for e in fleet.epochs[:10]]
    last = sols[-1]
    seeds = [
        VehicleSeed(vid, est.time, est.position_m, est.covariance_m2, dict(est.clocks_s))
        for vid, est in last.estimates.items()
    ]
    nxt = _no_gnss(fleet.epochs[10], "v01")  # v0 has no GNSS in the first epoch after the restart

    fresh = FusionEstimator(cfg).step(nxt)
    assert "v01" not in fresh.estimates and "v01" in fresh.skipped

    resumed = FusionEstimator(cfg)
    assert seed_estimator(resumed, seeds) == len(seeds)
    sol = resumed.step(nxt)
    assert sol.factor_counts.get("seed", 0) >= len(seeds)  # a position prior (+ clocks) each
    err = np.linalg.norm(fleet.enu_error(10, "v01", sol.estimates["v01"].position_m)[:2])
    assert err < 3.0, err  # carried by the seed, its velocity and its plane
    # the other vehicles: close to the estimator that never stopped
    cont = before.step(nxt)
    for vid in ("v02", "v03"):
        d = np.linalg.norm(sol.estimates[vid].position_m - cont.estimates[vid].position_m)
        assert d < 2.0, (vid, d)


def test_stale_or_future_seeds_are_ignored() -> None:
    fleet = make_fleet(n_vehicles=2, n_epochs=3, seed=5)
    e = fleet.epochs[2]
    est = FusionEstimator(FgoConfig())
    p = fleet.truth[2]["v01"]
    est.seed(VehicleSeed("v01", e.time + (-1000.0), p))  # too old
    est.seed(VehicleSeed("v02", e.time + 5.0, p))  # from the future
    sol = est.step(e)
    assert "seed" not in sol.factor_counts
    assert set(sol.estimates) == {"v01", "v02"}


def test_estimators_without_seed_ignore_seeds() -> None:
    class Plain:
        def step(self, epoch: EpochInput):  # type: ignore[no-untyped-def]
            raise AssertionError("not called")

    assert seed_estimator(Plain(), [VehicleSeed("v01", make_fleet(1, 1).epochs[0].time, np.zeros(3))]) == 0


def test_a_seed_carries_the_graphs_information_not_the_inflated_report() -> None:
    """Reports are scaled by `covariance_scale` for honest error bounds; a seed made from one
    must not weaken the track by that factor (squared) again: the hand-over between region
    servers drifted by up to 1.5 m before (docs/scale.md)."""
    fleet = make_fleet(n_vehicles=1, n_epochs=2, seed=6)
    e = fleet.epochs[1]
    cov = np.diag([4.0, 9.0, 16.0])
    for scale in (1.0, 4.5):
        est = FusionEstimator(FgoConfig(covariance_scale=scale))
        est.seed(VehicleSeed("v01", e.time + (-1.0), fleet.truth[1]["v01"], cov * scale**2))
        est.step(e)
        seeded = est._state.window.by_vehicle["v01"][0]
        assert seeded.counts.get("seed")
        np.testing.assert_allclose(est._state.cov[seeded.pos_key], cov, rtol=1e-9)


def test_the_window_is_epochs_of_time_not_calls() -> None:
    """An estimator not called for a while (a region server whose vehicles were elsewhere) must
    not link the next epoch to states from long ago: they leave the window as if it had been
    stepped, and the vehicle needs a seed (or its SPP) again."""
    fleet = make_fleet(n_vehicles=2, n_epochs=40, seed=7)
    est = FusionEstimator(FgoConfig())
    for e in fleet.epochs[:6]:
        est.step(e)
    late = fleet.epochs[30]
    assert est.tracked_vehicles == ["v01", "v02"]
    assert est.tracked_at(fleet.epochs[7].time) == ["v01", "v02"]  # one epoch missed: still held
    assert est.tracked_at(late.time) == []
    sol = est.step(late)
    assert "velocity" not in sol.factor_counts and "motion" not in sol.factor_counts
    assert set(sol.estimates) == {"v01", "v02"}  # started again from their SPP
