"""Motion and clock models for epochs without Doppler (FgoConfig's opt-ins `motion_accel_psd`,
`clock_accel_psd`, `clock_isb_sigma_m`): their factors, how the estimator builds them, and that
they cross to the smoother pool's processes."""

from __future__ import annotations

import dataclasses
import math
import pickle

import gtsam
import numpy as np
import pytest
from support.fgo_synthetic import make_fleet, run

from coplane.fgo import factors as F
from coplane.fgo.config import FgoConfig
from coplane.fgo.engine import FusionEstimator
from coplane.fgo.keys import bias_key, clock_key, position_key
from coplane.fgo.recipes import Recipe, from_wire, realise, to_wire
from coplane.geo import enu_rotation, geodetic_to_ecef
from coplane.gnss.constants import C
from coplane.methods import get_method
from coplane.parallel import smoothers_for

LAT, LON = math.radians(22.3), math.radians(114.17)
RX = geodetic_to_ecef(LAT, LON, 10.0)
ENU = enu_rotation(LAT, LON)
HONEST = {
    "motion_accel_psd": 0.25,
    "motion_accel_psd_up": 0.025,
    "clock_accel_psd": 0.1,
    "clock_isb_sigma_m": 0.5,
}


def _points(*xs: np.ndarray) -> gtsam.Values:
    v = gtsam.Values()
    for k, x in enumerate(xs):
        v.insertPoint3(k, x)
    return v


def _clocks(*bs: float) -> gtsam.Values:
    v = gtsam.Values()
    for k, b in enumerate(bs):
        v.insert(k, c=b)
    return v


def test_acceleration_factor_is_the_velocity_change_weighed_per_local_axis() -> None:
    f = F.acceleration_factor((0, 1, 2), 1.0, 2.0, 0.5, 0.1, RX)
    v = ENU.T @ np.array([3.0, 4.0, 0.0])
    assert f.error(_points(RX, RX + v, RX + v + 2.0 * v)) == pytest.approx(0.0, abs=1e-12)
    east, up = ENU.T @ np.array([1.0, 0.0, 0.0]), ENU.T @ np.array([0.0, 0.0, 1.0])
    # 1 m/s more east over the second interval (2 s): 1 m/s over sigma 0.5; up: 0.2 over 0.1
    assert f.error(_points(RX, RX + v, RX + v + 2.0 * (v + east))) == pytest.approx(0.5 * 4.0, rel=1e-6)
    assert f.error(_points(RX, RX + v, RX + v + 2.0 * (v + 0.2 * up))) == pytest.approx(0.5 * 4.0, rel=1e-6)


def test_clock_acceleration_factor_is_the_drift_change_in_metres_per_second() -> None:
    f = F.clock_acceleration_factor((0, 1, 2), 1.0, 1.0, 0.3)
    b0, drift_s = 1e-4, 200.0 / C
    assert f.error(_clocks(b0, b0 + drift_s, b0 + 2 * drift_s)) == pytest.approx(0.0, abs=1e-12)
    # the drift changes by 0.6 m/s: two sigma
    assert f.error(_clocks(b0, b0 + drift_s, b0 + 2 * drift_s + 0.6 / C)) == pytest.approx(2.0, rel=1e-6)


def test_a_systems_offset_from_the_receiver_clock_is_its_own_clock() -> None:
    """A pseudorange keyed on the receiver clock and the system's offset d = c (dt_ref - dt_s)
    (`factors.pseudorange_factors` with a correction key) has the error of the same pseudorange
    on the system's own clock dt_s: the sign and unit (metres) of GTSAM's correction variable."""
    sat = np.array([15_600e3, 7_540e3, 20_140e3])
    rho, dt_ref, dt_s = 2.2e7, 1e-4, 1e-4 + 30e-9
    own, offset = F.pseudorange_factors(
        position_key(0, 0),
        [clock_key(0, 0, "C"), clock_key(0, 0, "G")],
        [rho, rho],
        np.array([sat, sat]),
        [2e-7, 2e-7],
        [3.0, 3.0],
        RX,
        correction_keys=[None, bias_key(0, 0, "C")],
    )
    v = gtsam.Values()
    v.insertPoint3(position_key(0, 0), RX)
    v.insert(clock_key(0, 0, "C"), c=dt_s)
    v.insert(clock_key(0, 0, "G"), c=dt_ref)
    v.insert(bias_key(0, 0, "C"), c=C * (dt_ref - dt_s))
    assert isinstance(offset, gtsam.DifferentialPseudorangeFactor)
    assert offset.error(v) == pytest.approx(own.error(v), rel=1e-12) and own.error(v) > 1.0


def test_the_linear_factors_cross_to_the_smoother_pool_exactly() -> None:
    """The pool ships a graph as its recipes (GTSAM's serialisation refuses the linear factors'
    held clock doubles): rebuilt in the other process, each factor has the same error."""
    p = [position_key(0, k) for k in range(3)]
    c = [clock_key(0, k, "G") for k in range(3)]
    recipes = [
        Recipe(F.position_prior, p[0], RX, np.eye(3)),
        Recipe(F.acceleration_factor, (p[0], p[1], p[2]), 1.0, 1.0, 0.5, 0.1, RX),
        Recipe(F.clock_acceleration_factor, (c[0], c[1], c[2]), 1.0, 1.0, 0.3),
    ]
    g = realise(recipes)
    vals = gtsam.Values()
    for k, x in zip(p, (RX, RX + 1.0, RX + 3.0), strict=True):
        vals.insertPoint3(k, x)
    for k, b in zip(c, (0.0, 1e-8, 3e-8), strict=True):
        vals.insert(k, c=b)
    before = [g.at(i).error(vals) for i in range(3)]
    back = from_wire(pickle.loads(pickle.dumps(to_wire(recipes))))
    assert [back.at(i).error(vals) for i in range(3)] == before and min(before[1:]) > 0


def _three_satellites_without_doppler():  # type: ignore[no-untyped-def]
    """v01 keeps 3 satellites and no Doppler for 8 epochs (the estimator's fallbacks)."""
    limits = {("v01", k): 3 for k in range(10, 18)}
    return make_fleet(4, 24, seed=8, sat_limit=limits, nlos_per_vehicle=1, nlos_bias=(10.0, 30.0))


@pytest.mark.parametrize("solver", ["isam2-fixed-lag", "batch-fixed-lag"])
def test_the_estimator_builds_them_and_stays_on_the_road(solver: str) -> None:
    fleet = _three_satellites_without_doppler()
    base = get_method("non-cp", solver=solver).fgo  # type: ignore[arg-type]
    assert base is not None and base.motion_accel_psd is None and base.clock_accel_psd is None
    cfg = dataclasses.replace(base, **HONEST)  # type: ignore[arg-type]
    est = FusionEstimator(cfg)
    for k, epoch in enumerate(fleet.epochs):
        sol = est.step(epoch)
        v01 = sol.estimates["v01"]
        assert np.linalg.norm(v01.position_m - fleet.truth[k]["v01"]) < 20.0
        if k in range(12, 18):  # two earlier states in the window: the three-state links
            links = [ln.kind for b in est._state.window.by_vehicle["v01"] for ln in b.links]
            assert "motion" in links
            last = est._state.window.by_vehicle["v01"][-1]
            assert any(isinstance(ln.factor(), gtsam.LinearContainerFactor) for ln in last.links)


def test_one_receiver_clock_and_an_offset_per_other_system() -> None:
    """Each state has one clock (the first system seen) and an offset per other system, linked to
    the previous one; the reported clocks per system are the receiver clock less the offset, and
    the offset stays the receiver's constant hardware bias (the synthetic fleet's is constant)."""
    fleet = _three_satellites_without_doppler()
    cfg = get_method("non-cp").fgo
    assert cfg is not None and cfg.clock_isb_sigma_m == 0.5  # a default of the methods
    est = FusionEstimator(cfg)
    for epoch in fleet.epochs[:10]:
        sol = est.step(epoch)
    blocks = list(est._state.window.by_vehicle["v02"])
    assert all(
        b.clock_ref == "C" and set(b.clock_keys) == {"C"} and set(b.bias_keys) == {"G"} for b in blocks
    )
    assert all([ln.kind for ln in b.links].count("clock_bias") == 1 for b in blocks[1:])
    offsets = [est._state.clock(b.bias_keys["G"]) for b in blocks]
    assert max(offsets) - min(offsets) < 0.5
    clocks = sol.estimates["v02"].clocks_s
    assert set(clocks) == {"C", "G"}
    assert C * (clocks["C"] - clocks["G"]) == pytest.approx(offsets[-1], abs=1e-6)


def test_the_receiver_clock_goes_on_through_epochs_without_its_system() -> None:
    """The reference stays the vehicle's first system when epochs have none of its satellites:
    its clock is then carried by the clock link and the other system's offset, and the track
    stays where it was."""
    fleet = make_fleet(2, 12, seed=3)
    for k in range(5, 8):  # v01 sees no BeiDou satellite (its reference) for three epochs
        vin = fleet.epochs[k].vehicles["v01"]
        gps = tuple(o for o in vin.pseudoranges if not o.sat.startswith("C"))
        fleet.epochs[k].vehicles["v01"] = dataclasses.replace(vin, pseudoranges=gps)
    cfg = get_method("non-cp").fgo
    assert cfg is not None
    est = FusionEstimator(cfg)
    for k, epoch in enumerate(fleet.epochs):
        sol = est.step(epoch)
        err = float(np.linalg.norm(sol.estimates["v01"].position_m - fleet.truth[k]["v01"]))
        if k == 4:
            before = err
        if k in range(5, 8):
            blk = est._state.window.by_vehicle["v01"][-1]
            assert blk.clock_ref == "C" and set(blk.clock_keys) == {"C"} and set(blk.bias_keys) == {"G"}
            assert {ln.kind for ln in blk.links} >= {"clock", "clock_bias"}
            assert err < before + 0.5  # measured: 2.4 m before, 2.2-2.4 m without BeiDou


def test_where_the_three_state_links_do_not_apply_the_estimates_are_the_defaults() -> None:
    """The three-state links restricted to epochs with a single pseudorange (none here) change no
    bit against the defaults, which build none of them. (That a change left the defaults where
    they were is checked against the previous commit with bench/solution_digest.py.)"""
    fleet = _three_satellites_without_doppler()
    cfg = get_method("non-cp").fgo
    assert cfg is not None and cfg.motion_accel_psd is None and cfg.clock_accel_psd is None
    a = run(fleet, cfg)
    b = run(fleet, dataclasses.replace(cfg, **HONEST, three_state_max_pseudoranges=1))  # type: ignore[arg-type]
    for sa, sb in zip(a, b, strict=True):
        for vid, ea in sa.estimates.items():
            assert np.array_equal(ea.position_m, sb.estimates[vid].position_m)
    est = FusionEstimator(cfg)
    for epoch in fleet.epochs:
        est.step(epoch)
    for hist in est._state.window.by_vehicle.values():
        assert all(blk.bias_keys for blk in hist)  # two systems in every epoch of this fleet
        for blk in hist:  # a three-state link is a linear factor
            assert not any(isinstance(ln.factor(), gtsam.LinearContainerFactor) for ln in blk.links)


def test_two_smoother_processes_give_the_same_estimates() -> None:
    fleet = _three_satellites_without_doppler()
    base = get_method("non-cp").fgo
    assert base is not None
    cfg = dataclasses.replace(base, **HONEST)  # type: ignore[arg-type]
    seq = run(fleet, cfg)
    est = FusionEstimator(cfg, smoothers=smoothers_for(cfg, 2))
    try:
        par = [est.step(e) for e in fleet.epochs]
    finally:
        est.close()
    for sa, sb in zip(seq, par, strict=True):
        for vid, ea in sa.estimates.items():
            assert np.array_equal(ea.position_m, sb.estimates[vid].position_m), (sa.time, vid)


@pytest.mark.parametrize(
    "field",
    [
        "motion_accel_psd",
        "motion_accel_psd_up",
        "clock_accel_psd",
        "clock_isb_sigma_m",
        "three_state_max_pseudoranges",
    ],
)
def test_bad_settings_are_refused_by_name(field: str) -> None:
    with pytest.raises(ValueError, match=field):
        FgoConfig(**{field: -1})  # type: ignore[arg-type]


def test_the_paper_window_refuses_the_three_state_links() -> None:
    """The lm-window would drop such a link with its oldest state and leave the next one free."""
    for field in ("motion_accel_psd", "clock_accel_psd"):
        with pytest.raises(ValueError, match="fixed-lag smoother"):
            FgoConfig(solver="lm-window", **{field: 0.1})  # type: ignore[arg-type]
    FgoConfig(solver="isam2-fixed-lag", motion_accel_psd=0.1, clock_accel_psd=0.1)
