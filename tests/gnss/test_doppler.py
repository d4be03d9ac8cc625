"""Direct tests of `coplane.gnss.doppler`: velocity and clock drift from Doppler by least squares.

The synthetic Doppler is built independently of the solver's linearised model: the range rate is
a central finite difference of the geometric range with an Earth-rotation (Sagnac) term between a
moving satellite and a moving receiver, plus the receiver drift, minus the satellite clock drift,
converted to a RINEX Doppler (positive when approaching) with the system's wavelength.

The solver's Sagnac range-rate term is the time derivative of the Sagnac range term in
`coplane.gnss.geometry.sagnac_ranges` (and of the simulator's `coplane.sim.sky.range_rate`). RTKLIB's
`resdop` has the opposite sign (RTKLIB issue #764), which biased velocities by about 1 cm/s;
`test_sagnac_rate_is_derivative_of_sagnac_range` pins the physical sign, and the RTKLIB sign must
now miss by about that much (`test_rtklib_sign_is_about_a_cm_per_s_off`).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import coplane.gnss.doppler as doppler
from coplane.geo import enu_rotation, geodetic_to_ecef
from coplane.gnss.constants import OMEGA_E_GPS, WAVELENGTH, C
from coplane.gnss.doppler import DopplerOptions, DriftPrior, solve_doppler_velocity
from coplane.gnss.ephemeris import SatState
from coplane.gnss.epoch_solver import EpochResult, ReceiverMemory, next_drift_prior
from coplane.gnss.measurements import PreparedEpoch, SatMeasurement
from coplane.gnss.spp import SppSolution
from coplane.gnss.weighting import doppler_sigma_mps
from coplane.gtime import GpsTime

T0 = GpsTime(2320, 115800.0)
LAT, LON = math.radians(22.3), math.radians(114.2)
RX = geodetic_to_ecef(LAT, LON, 10.0)
V_RX = np.array([12.0, -7.5, 3.25])  # m/s, ECEF
DRIFT = 123.4  # receiver clock drift, m/s
SAT_RADIUS = 2.66e7
# sign of the Sagnac term whose time derivative is the Sagnac range rate: +1 is the derivative of
# geometry.sagnac_ranges (physical, what solve_doppler_velocity models), -1 RTKLIB resdop's sign
PHYSICAL_SAGNAC = 1.0
RTKLIB_SAGNAC = -1.0
SOLVER_SAGNAC = PHYSICAL_SAGNAC

# (sat, azimuth deg, elevation deg): a spread of GPS and BeiDou satellites above the 10 deg mask
SKY = [
    ("C14", 20.0, 70.0),
    ("C21", 250.0, 25.0),
    ("G02", 0.0, 45.0),
    ("G05", 90.0, 30.0),
    ("G07", 180.0, 60.0),
    ("G09", 270.0, 20.0),
    ("G13", 135.0, 80.0),
    ("G16", 315.0, 35.0),
]


def _sat_position(az_deg: float, el_deg: float) -> np.ndarray:
    """A satellite at SAT_RADIUS from the Earth's centre, seen at (az, el) from RX."""
    az, el = math.radians(az_deg), math.radians(el_deg)
    enu = np.array([math.cos(el) * math.sin(az), math.cos(el) * math.cos(az), math.sin(el)])
    e = enu_rotation(LAT, LON).T @ enu
    pe = float(RX @ e)
    rho = -pe + math.sqrt(pe * pe - float(RX @ RX) + SAT_RADIUS**2)
    return RX + rho * e


def _sat_velocity(pos: np.ndarray, k: int) -> np.ndarray:
    """About 3.9 km/s, perpendicular to the radius, in a direction that differs per satellite."""
    r = pos / np.linalg.norm(pos)
    a = np.cross(r, [0.0, 0.0, 1.0])
    a /= np.linalg.norm(a)
    b = np.cross(r, a)
    ang = 0.7 * k
    return 3900.0 * (math.cos(ang) * a + math.sin(ang) * b)


def _sagnac_range(ps: np.ndarray, p: np.ndarray, sagnac: float) -> float:
    return float(np.linalg.norm(ps - p)) + sagnac * OMEGA_E_GPS * (ps[0] * p[1] - ps[1] * p[0]) / C


def _true_range_rate(
    ps: np.ndarray, vs: np.ndarray, sat_drift: float, v_rx: np.ndarray, drift: float, sagnac: float
) -> float:
    """d/dt of the Sagnac range (central difference) + receiver drift - c * satellite clock drift."""
    h = 0.1
    plus = _sagnac_range(ps + vs * h, RX + v_rx * h, sagnac)
    minus = _sagnac_range(ps - vs * h, RX - v_rx * h, sagnac)
    return (plus - minus) / (2 * h) + drift - C * sat_drift


def _sat(
    sat: str,
    az: float,
    el: float,
    k: int,
    *,
    doppler_offset_hz: float = 0.0,
    v_rx: np.ndarray = V_RX,
    drift: float = DRIFT,
    sagnac: float = SOLVER_SAGNAC,
) -> SatMeasurement:
    ps = _sat_position(az, el)
    vs = _sat_velocity(ps, k)
    sat_drift = (k - 3) * 1e-11
    rate = _true_range_rate(ps, vs, sat_drift, v_rx, drift, sagnac)
    doppler = -rate / WAVELENGTH[sat[0]] + doppler_offset_hz  # RINEX sign: range rate = -lambda * D
    state = SatState(sat, ps, vs, 1e-5, sat_drift, None, 1.0)  # type: ignore[arg-type]  # eph unused
    return SatMeasurement(sat, state, 2.2e7, doppler, 45.0, 0.0)


def _epoch(
    sky: list[tuple[str, float, float]] = SKY,
    offsets: dict[str, float] | None = None,
    v_rx: np.ndarray = V_RX,
    drift: float = DRIFT,
    sagnac: float = SOLVER_SAGNAC,
) -> PreparedEpoch:
    offsets = offsets or {}
    sats = tuple(
        _sat(s, az, el, k, doppler_offset_hz=offsets.get(s, 0.0), v_rx=v_rx, drift=drift, sagnac=sagnac)
        for k, (s, az, el) in enumerate(sky)
    )
    return PreparedEpoch(T0, sats, ())


def test_exact_recovery_without_noise() -> None:
    """Noise-free Doppler of GPS and BeiDou satellites gives back the receiver velocity and drift."""
    res = solve_doppler_velocity(_epoch(), RX)
    assert res.ok, res.reason
    assert res.time == T0
    np.testing.assert_allclose(res.velocity_mps, V_RX, atol=1e-5)
    assert res.drift_mps == pytest.approx(DRIFT, abs=1e-5)
    assert res.used == tuple(s for s, _, _ in SKY)
    assert res.excluded == ()
    assert set(res.residuals_mps) == set(res.used)
    assert max(abs(v) for v in res.residuals_mps.values()) < 1e-5


def test_physical_doppler_within_a_few_cm_per_s() -> None:
    """Doppler from the physical Sagnac range rate (as the simulator makes it) gives the velocity to 3 cm/s."""
    res = solve_doppler_velocity(_epoch(sagnac=PHYSICAL_SAGNAC), RX)
    assert res.ok and res.excluded == ()
    assert float(np.linalg.norm(res.velocity_mps - V_RX)) < 0.03
    assert res.drift_mps == pytest.approx(DRIFT, abs=0.03)


def test_sagnac_rate_is_derivative_of_sagnac_range() -> None:
    """The solver's Sagnac range-rate term is the time derivative of the Sagnac range term (exact recovery)."""
    res = solve_doppler_velocity(_epoch(sagnac=PHYSICAL_SAGNAC), RX)
    np.testing.assert_allclose(res.velocity_mps, V_RX, atol=1e-5)


def test_rtklib_sign_is_about_a_cm_per_s_off() -> None:
    """Doppler made with RTKLIB resdop's Sagnac sign is off by the size of the term: it is not noise."""
    res = solve_doppler_velocity(_epoch(sagnac=RTKLIB_SAGNAC), RX)
    assert 0.002 < float(np.linalg.norm(res.velocity_mps - V_RX)) < 0.05


def test_range_rate_sign_is_rinex() -> None:
    """A positive Doppler is an approaching satellite: range rate = -wavelength * Doppler, per system."""
    g = _sat("G05", 90.0, 30.0, 0)
    c = _sat("C14", 20.0, 70.0, 0)
    assert g.range_rate_mps == pytest.approx(-WAVELENGTH["G"] * g.doppler_hz)
    assert c.range_rate_mps == pytest.approx(-WAVELENGTH["C"] * c.doppler_hz)
    assert WAVELENGTH["C"] > WAVELENGTH["G"]  # B1I is below L1


def test_covariance_is_symmetric_positive_and_matches_scatter() -> None:
    """The reported 3x3 covariance is SPD and agrees with the scatter of solutions under its own noise model."""
    ep = _epoch()
    res0 = solve_doppler_velocity(ep, RX)
    cov = res0.covariance
    assert cov.shape == (3, 3)
    np.testing.assert_allclose(cov, cov.T, rtol=1e-12, atol=0.0)
    assert np.all(np.linalg.eigvalsh(cov) > 0)
    # sigmas of the weighting model the solver uses, applied as noise to the range rates
    p = RX
    els = []
    for m in ep.sats:
        d = m.state.pos - p
        els.append(math.asin(float(enu_rotation(LAT, LON)[2] @ d) / float(np.linalg.norm(d))))
    sig = doppler_sigma_mps(np.array(els), np.full(len(els), 45.0), [m.system for m in ep.sats])
    rng = np.random.default_rng(7)
    errs = []
    for _ in range(400):
        noise = rng.normal(0.0, sig)
        sats = tuple(
            SatMeasurement(
                m.sat, m.state, m.pseudorange_m, m.doppler_hz - n / WAVELENGTH[m.system], 45.0, 0.0
            )
            for m, n in zip(ep.sats, noise, strict=True)
        )
        r = solve_doppler_velocity(PreparedEpoch(T0, sats, ()), p)
        if r.ok and not r.excluded:
            errs.append(r.velocity_mps - V_RX)
    e = np.array(errs)
    assert len(e) > 350
    emp = e.T @ e / len(e)
    ratio = np.trace(emp) / np.trace(cov)
    assert 0.8 < ratio < 1.25, ratio
    assert 0.01 < math.sqrt(np.trace(cov) / 3) < 1.0  # centimetres to decimetres per second


def test_fde_removes_one_corrupted_doppler() -> None:
    """One Doppler off by 40 Hz (about 8 m/s) is excluded and the rest recover the truth exactly."""
    res = solve_doppler_velocity(_epoch(offsets={"G07": 40.0}), RX)
    assert res.ok, res.reason
    assert res.excluded == ("G07",)
    assert "G07" not in res.used and len(res.used) == len(SKY) - 1
    np.testing.assert_allclose(res.velocity_mps, V_RX, atol=1e-5)
    assert res.drift_mps == pytest.approx(DRIFT, abs=1e-5)


def test_fault_without_exclusions_allowed_is_not_ok() -> None:
    """With no exclusion allowed, a corrupted Doppler fails the residual test with a reason."""
    res = solve_doppler_velocity(_epoch(offsets={"G07": 40.0}), RX, DopplerOptions(max_exclusions=0))
    assert not res.ok
    assert res.reason == "Doppler residual test failed after 0 exclusions (cannot exclude 1 more)"
    assert np.all(np.isnan(res.velocity_mps)) and math.isnan(res.drift_mps)


def test_a_group_exclusion_keeps_the_limit(monkeypatch: pytest.MonkeyPatch) -> None:
    """A fault several satellites share goes with all of them (`lsq.worst_rows`), never past
    `max_exclusions`: a pair with one exclusion left fails instead. The pair is forced here."""
    real_worst = doppler.worst_rows
    monkeypatch.setattr(
        doppler, "worst_rows", lambda a, v, s, rows: np.union1d(real_worst(a, v, s, rows), [0])
    )
    res = solve_doppler_velocity(_epoch(offsets={"G07": 40.0}), RX, DopplerOptions(max_exclusions=1))
    assert not res.ok and res.excluded == ()
    assert res.reason == "Doppler residual test failed after 0 exclusions (cannot exclude 2 more)"
    assert len(solve_doppler_velocity(_epoch(offsets={"G07": 40.0}), RX).excluded) == 2


def test_a_fault_with_one_redundant_doppler_is_not_pinned_on_a_satellite() -> None:
    """Five satellites, four unknowns: every residual is the same test, so no satellite can be
    told faulty; the velocity fails with that reason instead of dropping one picked by rounding."""
    sky = SKY[:5]
    res = solve_doppler_velocity(
        _epoch(sky, offsets={sky[0][0]: 40.0}), RX, DopplerOptions(few_satellites=False)
    )
    assert not res.ok
    assert res.reason.startswith("Doppler residual test failed and no satellite can be told faulty")
    assert res.excluded == ()


def test_too_few_satellites_is_not_ok_with_reason() -> None:
    """Paper mode: four satellites (four unknowns, no redundancy) give not-ok and say how many."""
    res = solve_doppler_velocity(_epoch(SKY[:4]), RX, DopplerOptions(few_satellites=False))
    assert not res.ok
    assert res.reason == "too few Doppler measurements: 4 < 5"
    assert res.used == ()
    assert np.all(np.isnan(res.covariance))


def test_too_few_after_exclusion_reports_the_exclusion() -> None:
    """Six satellites, one corrupted, min_satellites 6: the exclusion leaves too few and is reported."""
    res = solve_doppler_velocity(
        _epoch(SKY[:6], {"G05": 40.0}), RX, DopplerOptions(min_satellites=6, few_satellites=False)
    )
    assert not res.ok
    assert res.excluded == ("G05",)
    assert res.reason == "too few Doppler measurements: 5 < 6"


def test_nan_doppler_is_skipped() -> None:
    """A satellite without Doppler (NaN) is neither used nor excluded; the others still solve exactly."""
    ep = _epoch()
    sats = tuple(
        SatMeasurement(m.sat, m.state, m.pseudorange_m, math.nan, m.cn0_dbhz, m.tgd_m)
        if m.sat == "G09"
        else m
        for m in ep.sats
    )
    res = solve_doppler_velocity(PreparedEpoch(T0, sats, ()), RX)
    assert res.ok, res.reason
    assert "G09" not in res.used and res.excluded == ()
    assert len(res.used) == len(SKY) - 1
    np.testing.assert_allclose(res.velocity_mps, V_RX, atol=1e-5)


def test_all_nan_doppler_is_too_few() -> None:
    """An epoch with no Doppler at all is not-ok (0 measurements), not an exception."""
    ep = _epoch()
    sats = tuple(SatMeasurement(m.sat, m.state, m.pseudorange_m, math.nan, 45.0, 0.0) for m in ep.sats)
    res = solve_doppler_velocity(PreparedEpoch(T0, sats, ()), RX)
    assert not res.ok
    assert res.reason == "too few Doppler measurements: 0 < 5"


def test_elevation_mask_drops_low_satellites() -> None:
    """A satellite at 5 deg elevation is dropped by the default 10 deg mask and kept with a 0 deg mask."""
    sky = [*SKY, ("G30", 45.0, 5.0)]
    res = solve_doppler_velocity(_epoch(sky), RX)
    assert res.ok and "G30" not in res.used and res.excluded == ()
    res0 = solve_doppler_velocity(_epoch(sky), RX, DopplerOptions(elevation_mask_deg=0.0))
    assert res0.ok and "G30" in res0.used
    np.testing.assert_allclose(res0.velocity_mps, V_RX, atol=1e-5)


def test_static_receiver_without_drift() -> None:
    """A receiver at rest with a zero drift gets zero velocity (no bias from the Sagnac terms)."""
    res = solve_doppler_velocity(_epoch(v_rx=np.zeros(3), drift=0.0), RX)
    assert res.ok
    np.testing.assert_allclose(res.velocity_mps, 0.0, atol=1e-5)
    assert res.drift_mps == pytest.approx(0.0, abs=1e-5)


# -- few-satellite mode: a level road and the receiver's drift memory ----------------------------

FEW = DopplerOptions()
PAPER = DopplerOptions(few_satellites=False)
V_LEVEL = enu_rotation(LAT, LON).T @ np.array([11.0, -6.0, 0.0])  # a car on a level road, ECEF
OPEN4 = [("G02", 0.0, 45.0), ("G05", 90.0, 30.0), ("C21", 250.0, 25.0), ("G13", 135.0, 80.0)]


def test_paper_mode_needs_five_satellites() -> None:
    """With the few-satellite mode off, four satellites stay too few, as in the paper."""
    res = solve_doppler_velocity(_epoch(OPEN4, v_rx=V_LEVEL), RX, PAPER, DriftPrior(DRIFT, T0 + -1.0))
    assert not res.ok and "too few" in (res.reason or "")


def test_four_satellites_on_a_level_road() -> None:
    """Four Doppler plus the level-road row: the velocity and drift come back, flagged few-satellite."""
    res = solve_doppler_velocity(_epoch(OPEN4, v_rx=V_LEVEL), RX, FEW)
    assert res.ok, res.reason
    assert res.few_satellites
    np.testing.assert_allclose(res.velocity_mps, V_LEVEL, atol=1e-4)
    assert res.drift_mps == pytest.approx(DRIFT, abs=1e-4)


def test_three_satellites_need_a_recent_drift() -> None:
    """Three satellites solve only with the drift memory, and only while it is recent."""
    ep = _epoch(OPEN4[:3], v_rx=V_LEVEL)
    assert not solve_doppler_velocity(ep, RX, FEW).ok
    stale = DriftPrior(DRIFT, T0 + -(FEW.drift_max_age_s + 1.0))
    assert not solve_doppler_velocity(ep, RX, FEW, stale).ok
    res = solve_doppler_velocity(ep, RX, FEW, DriftPrior(DRIFT, T0 + -2.0))
    assert res.ok, res.reason
    np.testing.assert_allclose(res.velocity_mps, V_LEVEL, atol=1e-3)


def test_weak_few_satellite_velocity_is_refused() -> None:
    """Three satellites nearly in one vertical plane (east, west, zenith) leave the north speed to
    the drift memory alone: weaker than a full-sky velocity, so no velocity, with why."""
    weak = [("G13", 135.0, 80.0), ("G05", 90.0, 30.0), ("G09", 270.0, 20.0)]
    res = solve_doppler_velocity(_epoch(weak, v_rx=V_LEVEL), RX, FEW, DriftPrior(DRIFT, T0 + -2.0))
    assert not res.ok
    assert "too weak" in (res.reason or "")


def test_few_satellites_fault_is_not_a_silent_velocity() -> None:
    """A 40 Hz fault among four satellites: excluded or refused, never a wrong velocity passed on."""
    ep = _epoch(OPEN4, {"G05": 40.0}, v_rx=V_LEVEL)
    res = solve_doppler_velocity(ep, RX, FEW, DriftPrior(DRIFT, T0 + -1.0))
    assert not res.ok or float(np.linalg.norm(res.velocity_mps - V_LEVEL)) < 0.05


def test_drift_memory_is_renewed_by_a_full_sky_only() -> None:
    """A few-satellite drift leans on the memory: it must not reset the memory's age."""
    old = DriftPrior(DRIFT, T0 + -10.0)
    few = EpochResult(
        PreparedEpoch(T0, (), ()), None, solve_doppler_velocity(_epoch(OPEN4, v_rx=V_LEVEL), RX, FEW), None
    )  # type: ignore[arg-type]
    assert few.velocity is not None and few.velocity.ok
    assert next_drift_prior(old, few) is old
    full = EpochResult(PreparedEpoch(T0, (), ()), None, solve_doppler_velocity(_epoch(), RX), None)  # type: ignore[arg-type]
    renewed = next_drift_prior(old, full)
    assert renewed is not None and renewed.time == T0 and renewed.drift_mps == pytest.approx(DRIFT, abs=1e-4)


def test_receiver_memory_keeps_the_last_fix_and_the_drift_memory() -> None:
    """`ReceiverMemory`, the state `coplane spp` and the vehicle step share: a failed SPP keeps
    the previous fix (the next SPP starts there), and the drift memory follows `next_drift_prior`."""
    memory = ReceiverMemory()
    full = solve_doppler_velocity(_epoch(), RX)
    fix = SppSolution(T0, True, position=RX + 1.0)
    memory.update(EpochResult(PreparedEpoch(T0, (), ()), fix, full, None))
    assert memory.fix is not None and np.array_equal(memory.fix, RX + 1.0)
    assert memory.drift is not None and memory.drift.time == T0
    memory.update(
        EpochResult(PreparedEpoch(T0 + 1.0, (), ()), SppSolution(T0 + 1.0, False, "no"), None, None)
    )
    assert np.array_equal(memory.fix, RX + 1.0) and memory.drift.time == T0


@pytest.mark.parametrize(
    ("changes", "field"),
    [
        ({"few_min_satellites": 2}, "few_min_satellites"),
        ({"few_max_sigma_mps": -0.6}, "few_max_sigma_mps"),
        ({"drift_wander_mps_per_s": float("nan")}, "drift_wander_mps_per_s"),
        ({"drift_max_age_s": 0.0}, "drift_max_age_s"),
    ],
)
def test_bad_few_satellite_options_are_refused_by_name(changes: dict[str, float], field: str) -> None:
    with pytest.raises(ValueError, match=field):
        DopplerOptions(**changes)  # type: ignore[arg-type]
