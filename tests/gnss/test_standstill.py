"""Standstill detection from a few Doppler measurements (`coplane.gnss.standstill`).

Uses the synthetic Doppler of test_doppler (an independent finite-difference range-rate model)."""

from __future__ import annotations

import numpy as np
import pytest
from test_doppler import DRIFT, RX, T0, V_LEVEL, _epoch

from coplane.gnss.doppler import DopplerOptions, DriftPrior, solve_doppler_velocity
from coplane.gnss.epoch_solver import EpochResult, ReceiverMemory, next_drift_prior
from coplane.gnss.measurements import PreparedEpoch
from coplane.gnss.spp import SppSolution
from coplane.gnss.standstill import DopplerNoise, StandstillOptions, noncentrality

STILL = np.zeros(3)
WIDE3 = [("G02", 0.0, 45.0), ("G05", 120.0, 30.0), ("C21", 240.0, 25.0)]  # three azimuths 120 deg apart
NEAR_PLANE = [("G13", 135.0, 80.0), ("G05", 90.0, 30.0), ("G09", 270.0, 20.0)]  # east, west, zenith


def test_three_standing_satellites_give_a_zero_velocity() -> None:
    """Three satellites spread in azimuth, receiver standing, no drift memory: a zero velocity
    flagged standstill, with the drift solved and the detectable speed as its sigma."""
    res = solve_doppler_velocity(_epoch(WIDE3, v_rx=STILL), RX)
    assert res.ok and res.standstill and res.few_satellites, res.reason
    np.testing.assert_array_equal(res.velocity_mps, 0.0)
    assert res.drift_mps == pytest.approx(DRIFT, abs=1e-3)
    sigma = float(np.sqrt(res.covariance[0, 0]))
    assert 0.0 < sigma <= StandstillOptions().max_detectable_speed_mps
    assert set(res.used) == {s for s, _, _ in WIDE3}


@pytest.mark.parametrize("speed", [3.0, 13.0])
def test_a_moving_car_is_not_standing(speed: float) -> None:
    """The same sky with the car driving: the test fails, and the few-satellite solve (with the
    drift memory) gives the real velocity instead."""
    v = V_LEVEL / np.linalg.norm(V_LEVEL) * speed
    ep = _epoch(WIDE3, v_rx=v)
    res = solve_doppler_velocity(ep, RX, drift_prior=DriftPrior(DRIFT, T0 + -1.0))
    assert not res.standstill
    assert res.ok, res.reason
    np.testing.assert_allclose(res.velocity_mps, v, atol=1e-3)


def test_blind_geometry_is_not_a_standstill() -> None:
    """Three satellites nearly in one vertical plane cannot see a north speed: the test would pass
    a car driving north, so it claims nothing."""
    north = np.cross(RX / np.linalg.norm(RX), [0.0, 0.0, 1.0])
    res = solve_doppler_velocity(_epoch(NEAR_PLANE, v_rx=STILL), RX)
    assert not res.standstill
    res = solve_doppler_velocity(_epoch(NEAR_PLANE, v_rx=north / np.linalg.norm(north) * 8.0), RX)
    assert not res.standstill


def test_full_sky_and_options() -> None:
    """A full sky is solved as before (no claim); the test can be switched off; the few-satellite
    switch of the paper's front end switches it off too."""
    assert not solve_doppler_velocity(_epoch(v_rx=STILL), RX).standstill
    off = DopplerOptions(standstill=StandstillOptions(enabled=False))
    assert not solve_doppler_velocity(_epoch(WIDE3, v_rx=STILL), RX, off).ok
    assert not solve_doppler_velocity(_epoch(WIDE3, v_rx=STILL), RX, DopplerOptions(few_satellites=False)).ok
    for bad in ({"power": 1.0}, {"max_detectable_speed_mps": float("nan")}, {"false_alarm_probability": 0.0}):
        with pytest.raises(ValueError, match="StandstillOptions"):
            StandstillOptions(**bad)  # type: ignore[arg-type]


def test_standstill_drift_does_not_renew_the_memory() -> None:
    """Like every few-satellite drift, a standstill's does not reset the drift memory's age."""
    old = DriftPrior(DRIFT, T0 + -10.0)
    res = EpochResult(
        PreparedEpoch(T0, (), ()), None, solve_doppler_velocity(_epoch(WIDE3, v_rx=STILL), RX), None
    )  # type: ignore[arg-type]
    assert next_drift_prior(old, res) is old


def test_noncentrality_gives_the_power() -> None:
    """Baarda's classic lambda_0: 1 degree of freedom, 0.1 % false alarms, 80 % power, 17.07 =
    (3.29 + 0.84)^2; more degrees of freedom need more."""
    assert noncentrality(0.001, 0.8, 1) == pytest.approx(17.07, abs=0.02)
    assert noncentrality(0.01, 0.8, 3) > noncentrality(0.01, 0.8, 2) > noncentrality(0.01, 0.8, 1)


def test_the_receiver_noise_is_learned_from_full_sky_solves() -> None:
    """The variance factor starts at 1, follows the full-sky solves' chi-square per degree of
    freedom (with the prior's weight kept), stays in its bounds, and ignores a solve without
    redundancy."""
    opt = StandstillOptions()
    noise = DopplerNoise()
    assert noise.factor(opt) == 1.0
    for _ in range(300):
        noise = noise.add(0.4, 4, opt)  # chi-square per dof 0.1
    saturated_dof = 4 * opt.noise_memory_epochs
    want = (0.1 * saturated_dof + opt.noise_prior_dof) / (saturated_dof + opt.noise_prior_dof)
    assert noise.factor(opt) == pytest.approx(want, rel=1e-3)
    assert noise.add(float("nan"), 4, opt) is noise and noise.add(1.0, 0, opt) is noise
    assert DopplerNoise(1e6, 1.0).factor(opt) == opt.noise_factor_bounds[1]
    with pytest.raises(ValueError, match="noise_factor_bounds"):
        StandstillOptions(noise_factor_bounds=(2.0, 4.0))


def test_a_quiet_receiver_sees_a_standstill_the_model_cannot() -> None:
    """Three satellites nearly in one plane: at the model's Doppler sigmas the test could miss
    more than 2 m/s, so no claim; a receiver whose full-sky residuals are a tenth of the model's
    sees the same geometry well enough."""
    ep = _epoch(NEAR_PLANE, v_rx=STILL)
    assert not solve_doppler_velocity(ep, RX).standstill
    quiet = DopplerNoise(100.0, 1000.0)
    res = solve_doppler_velocity(ep, RX, noise=quiet)
    assert res.ok and res.standstill, res.reason


def test_receiver_memory_learns_from_full_sky_only() -> None:
    """`ReceiverMemory` adds a full-sky Doppler solve's residuals to its noise, never a
    few-satellite or standstill one."""
    memory = ReceiverMemory()
    full = solve_doppler_velocity(_epoch(v_rx=STILL, offsets={"G05": 0.05}), RX)
    assert full.ok and not full.few_satellites and full.dof > 0
    memory.update(EpochResult(PreparedEpoch(T0, (), ()), _no_fix(), full, None))
    learned = memory.doppler_noise
    assert learned.dof == full.dof and learned.chi2 == pytest.approx(full.chi2)
    still = solve_doppler_velocity(_epoch(WIDE3, v_rx=STILL), RX)
    memory.update(EpochResult(PreparedEpoch(T0, (), ()), _no_fix(), still, None))
    assert memory.doppler_noise is learned


def _no_fix() -> SppSolution:
    return SppSolution(T0, False, "test")
