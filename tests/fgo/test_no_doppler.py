"""Receivers without Doppler (an RTCM MSM4 stream, a pseudorange-only log): how the fusion server
tells them apart, what the factor graph's motion link does for them, and that receivers with
Doppler are left exactly as they were."""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
from support.fgo_synthetic import SyntheticFleet, make_fleet, run

from coplane.estimation.contract import EpochInput
from coplane.estimation.validate import validate_epoch
from coplane.fgo.config import FgoConfig
from coplane.fgo.engine import FusionEstimator
from coplane.fgo.links import _estimated_velocity, constant_drift, displacement
from coplane.fgo.state import GraphState
from coplane.fgo.window import Window
from coplane.geo import up_vector
from coplane.messages import NodeMessage
from coplane.methods import get_method
from coplane.steps.wire import doppler_observed
from tests.support.wire_payloads import node, sat, satellites


def test_the_node_message_says_whether_the_receiver_gave_doppler() -> None:
    """A velocity, or a Doppler on any satellite (a Doppler receiver whose velocity failed), is a
    receiver with Doppler; satellites without any is one without; no satellite says nothing."""
    assert doppler_observed(NodeMessage.model_validate(node())) is True
    assert doppler_observed(NodeMessage.model_validate(node(velocity=None))) is True
    none = satellites(sat(doppler_hz=None), sat(sat="C14", doppler_hz=None))
    assert doppler_observed(NodeMessage.model_validate(node(velocity=None, satellites=none))) is False
    assert doppler_observed(NodeMessage.model_validate(node(velocity=None, satellites=satellites()))) is None


def _inputs(fleet: SyntheticFleet, observed: Any) -> list[EpochInput]:
    """The fleet's epochs with no Doppler velocity or drift, and `doppler_observed` = `observed`."""
    out = []
    for e in fleet.epochs:
        vehicles = {
            v: dataclasses.replace(vin, velocity=None, clock_drift_mps=None, doppler_observed=observed)
            for v, vin in e.vehicles.items()
        }
        out.append(dataclasses.replace(e, vehicles=vehicles))
    return out


def test_a_doppler_observed_that_is_not_a_yes_or_no_is_counted() -> None:
    epoch = _inputs(make_fleet(1, 1, seed=3), "yes")[0]
    valid = validate_epoch(epoch)
    assert valid.rejected["doppler_observed"] == 1
    assert valid.vehicles["v01"].doppler_observed is True  # as a receiver with Doppler


def _motion_ups(fleet: SyntheticFleet, cfg: FgoConfig, observed: bool) -> list[float]:
    """Along local up, each new state's motion link displacement (m) of vehicle v01."""
    est = FusionEstimator(cfg)
    ups = []
    for epoch in _inputs(fleet, observed):
        est.step(epoch)
        last = est._state.window.by_vehicle["v01"][-1]
        for ln in last.links:
            if ln.kind == "motion":
                ups.append(float(np.asarray(ln.factor().measured()) @ up_vector(last.init_pos)))
    return ups


def test_a_receiver_without_doppler_extrapolates_only_horizontally() -> None:
    """On a tilted road the difference of two estimates climbs. A receiver that gives no Doppler
    extrapolates only its horizontal part (the height is held by the fallback's vertical sigma,
    not pushed by noise); one with Doppler in an outage keeps the 3-D difference."""
    fleet = make_fleet(2, 10, seed=5, velocity_sigma=0.05)
    cfg = get_method("non-cp").fgo
    assert cfg is not None and cfg.no_doppler_velocity == "horizontal"
    without = _motion_ups(fleet, cfg, observed=False)
    outage = _motion_ups(fleet, cfg, observed=True)
    assert len(without) == len(outage) >= 7
    # without: 1-2e-5 m (the up at the new state's start, not at the last estimate); outage: 0.5-2 cm
    assert max(abs(u) for u in without) < 1e-4
    assert max(abs(u) for u in outage) > 0.01


def test_its_link_loosens_with_the_estimates_covariance() -> None:
    """The velocity's variance is the configured share of the two estimates' summed covariances
    over dt^2: horizontal per axis, and none along up where nothing is extrapolated up."""
    up = up_vector(np.array([-2418077.0, 5386069.0, 2405174.0]))
    state = GraphState(window=Window(5))
    last, prev = SimpleNamespace(pos_key=1), SimpleNamespace(pos_key=0)
    state.values.insertPoint3(0, np.array([-2418077.0, 5386069.0, 2405174.0]))
    state.values.insertPoint3(1, np.array([-2418077.0, 5386069.0, 2405174.0]) + 10.0 * up)
    state.cov[0] = state.cov[1] = np.eye(3) * 4.0
    v = np.array([3.0, 0.0, 0.0]) + 10.0 * up
    cfg = FgoConfig(no_doppler_velocity="horizontal", no_doppler_velocity_covariance=0.25)
    got, var_h, var_up = _estimated_velocity(v, last, prev, 2.0, "horizontal", state, cfg)  # type: ignore[arg-type]
    assert abs(float(got @ up)) < 1e-9
    assert var_h == pytest.approx(0.25 * 8.0 / 4.0) and var_up == 0.0
    cfg3 = dataclasses.replace(cfg, no_doppler_velocity="estimates")
    got, var_h, var_up = _estimated_velocity(v, last, prev, 2.0, "estimates", state, cfg3)  # type: ignore[arg-type]
    assert np.array_equal(got, v) and var_up == pytest.approx(0.5)
    del state.cov[0]  # a covariance unknown: no variance added
    assert _estimated_velocity(v, last, prev, 2.0, "horizontal", state, cfg)[1:] == (0.0, 0.0)  # type: ignore[arg-type]


def test_the_height_of_a_receiver_without_doppler_has_its_own_sigma() -> None:
    """Without Doppler the height's link is `no_doppler_sigma_up` at every epoch; a Doppler
    receiver's outage keeps `motion_sigma_up` (and None falls back to it)."""
    p0 = np.array([-2418077.0, 5386069.0, 2405174.0])
    state = GraphState(window=Window(5))
    state.values.insertPoint3(0, p0)
    state.values.insertPoint3(1, p0 + np.array([3.0, 0.0, 0.0]))
    hist = [
        SimpleNamespace(vehicle_id="v01", pos_key=0, step=0, time=0.0, velocity=None),
        SimpleNamespace(vehicle_id="v01", pos_key=1, step=1, time=1.0, velocity=None),
    ]
    cfg = dataclasses.replace(get_method("pc").fgo, no_doppler_velocity_covariance=0.0)  # type: ignore[type-var]
    assert cfg.no_doppler_sigma_up == 0.4 and cfg.motion_sigma_up == 0.2
    without = displacement(hist, None, 2.0, state, cfg, no_doppler=True)  # type: ignore[arg-type]
    outage = displacement(hist, None, 2.0, state, cfg, no_doppler=False)  # type: ignore[arg-type]
    assert without.sigma_up == pytest.approx(0.4 * 2.0) and outage.sigma_up == pytest.approx(0.2 * 2.0)
    same = dataclasses.replace(cfg, no_doppler_sigma_up=None)
    assert displacement(hist, None, 2.0, state, same, no_doppler=True).sigma_up == pytest.approx(0.4)  # type: ignore[arg-type]


def test_no_velocity_is_made_across_a_track_restart() -> None:
    """A track restarted at its last state (the FDE found it diverged) must not extrapolate the
    difference between that state and the diverged one before it: that jump is no velocity. With
    the 3-D difference and no covariance, the real car without Doppler ran to thousands of
    kilometres that way (docs/fgo.md, "Receivers without Doppler")."""
    p0 = np.array([-2418077.0, 5386069.0, 2405174.0])
    state = GraphState(window=Window(5))
    state.values.insertPoint3(0, p0)
    state.values.insertPoint3(1, p0 + np.array([900.0, 0.0, 0.0]))  # restarted 900 m away
    hist = [
        SimpleNamespace(vehicle_id="v01", pos_key=0, step=0, time=0.0, velocity=None),
        SimpleNamespace(vehicle_id="v01", pos_key=1, step=1, time=1.0, velocity=None),
    ]
    cfg = dataclasses.replace(
        get_method("non-cp").fgo, no_doppler_velocity="estimates", no_doppler_velocity_covariance=0.0
    )  # type: ignore[type-var]
    state.track_start["v01"] = 0
    across = displacement(hist, None, 1.0, state, cfg, no_doppler=True)  # type: ignore[arg-type]
    assert np.allclose(across.displacement, [900.0, 0.0, 0.0])  # the same track: its velocity
    state.track_start["v01"] = 1  # the last state restarted the track
    after = displacement(hist, None, 1.0, state, cfg, no_doppler=True)  # type: ignore[arg-type]
    assert np.array_equal(after.displacement, np.zeros(3)) and after.sigma == pytest.approx(cfg.max_speed)


def test_no_clock_drift_is_made_across_a_track_restart() -> None:
    """The opt-in constant-drift clock link (`clock_accel_psd`) takes the drift between the last
    two clocks; across a track restart that is the restart's jump too, so it is not made."""
    state = GraphState(window=Window(5))
    state.values.insert(10, c=0.0)
    state.values.insert(11, c=1e-3)  # the restarted clock, 300 km of range away
    hist = [
        SimpleNamespace(vehicle_id="v01", step=0, time=0.0, clock_keys={"G": 10}),
        SimpleNamespace(vehicle_id="v01", step=1, time=1.0, clock_keys={"G": 11}),
    ]
    cfg = FgoConfig(solver="isam2-fixed-lag", clock_accel_psd=0.1)
    state.track_start["v01"] = 0
    assert constant_drift(hist, hist[-1], "G", 1.0, state, cfg) is not None  # type: ignore[arg-type]
    state.track_start["v01"] = 1
    assert constant_drift(hist, hist[-1], "G", 1.0, state, cfg) is None  # type: ignore[arg-type]


def test_receivers_with_doppler_are_not_touched() -> None:
    """The new settings act on receivers without Doppler only: a fleet with Doppler (and one whose
    velocity fails while its receiver still reports Doppler) gives the same bits with the
    previous behaviour (the 3-D difference, no covariance)."""
    fleet = make_fleet(3, 12, seed=21)
    cfg = get_method("pc").fgo
    assert cfg is not None
    old = dataclasses.replace(
        cfg, no_doppler_velocity="estimates", no_doppler_velocity_covariance=0.0, no_doppler_sigma_up=None
    )
    for epochs in (fleet.epochs, _inputs(fleet, True)):
        a, b = run(fleet, cfg, epochs), run(fleet, old, epochs)
        for sa, sb in zip(a, b, strict=True):
            for vid, ea in sa.estimates.items():
                assert np.array_equal(ea.position_m, sb.estimates[vid].position_m)


@pytest.mark.parametrize(
    ("field", "value"),
    [("no_doppler_velocity", "3d"), ("no_doppler_velocity_covariance", -1.0), ("no_doppler_sigma_up", 0.0)],
)
def test_bad_settings_are_refused_by_name(field: str, value: object) -> None:
    with pytest.raises(ValueError, match=field):
        FgoConfig(**{field: value})  # type: ignore[arg-type]
