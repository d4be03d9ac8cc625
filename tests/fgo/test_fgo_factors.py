"""Factor builders (coplane.fgo.factors) and keys: measurement models, signs and Jacobians."""

from __future__ import annotations

import math

import gtsam
import numpy as np
import pytest

from coplane.estimation.contract import PlaneObs
from coplane.fgo import factors as F
from coplane.fgo.keys import KeyRegistry, clock_key, decode_key, position_key
from coplane.geo import enu_rotation, geodetic_to_ecef
from coplane.gnss.constants import OMEGA_E_GPS, C

LAT, LON = math.radians(39.98), math.radians(116.32)
RX = geodetic_to_ecef(LAT, LON, 50.0)
ENU = enu_rotation(LAT, LON)


def _sat(az_deg: float, el_deg: float, radius: float = 26_560e3) -> np.ndarray:
    az, el = math.radians(az_deg), math.radians(el_deg)
    u = ENU.T @ np.array([math.cos(el) * math.sin(az), math.cos(el) * math.cos(az), math.sin(el)])
    b = float(RX @ u)
    return RX + (-b + math.sqrt(b * b - (RX @ RX - radius**2))) * u


def _rotate_z(v: np.ndarray, theta: float) -> np.ndarray:
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]]) @ v


def _values(entries: dict[int, np.ndarray | float]) -> gtsam.Values:
    v = gtsam.Values()
    for k, x in entries.items():
        v.insert(k, x)
    return v


def _numeric_jacobian(
    factor: gtsam.NoiseModelFactor, entries: dict[int, np.ndarray | float], steps: dict[int, float]
):
    """Central differences of unwhitenedError, blocks in factor.keys() order."""
    cols = []
    for key in factor.keys():  # noqa: SIM118 (a gtsam factor, not a dict)
        x = entries[key]
        h = steps[key]
        dim = 3 if isinstance(x, np.ndarray) else 1
        for i in range(dim):
            plus, minus = dict(entries), dict(entries)
            if dim == 3:
                e = np.zeros(3)
                e[i] = h
                plus[key] = x + e
                minus[key] = x - e
            else:
                plus[key] = x + h
                minus[key] = x - h
            diff = factor.unwhitenedError(_values(plus)) - factor.unwhitenedError(_values(minus))
            cols.append(diff / (2 * h))
    return np.column_stack(cols)


def _analytic_jacobian(factor: gtsam.NoiseModelFactor, entries: dict[int, np.ndarray | float], sigma: float):
    a, _ = factor.linearize(_values(entries)).jacobian()
    return np.asarray(a) * sigma  # isotropic noise: A = J / sigma


# ---------------------------------------------------------------------------------------------
# pseudorange


def test_native_pseudorange_factor_adds_sagnac_itself() -> None:
    """GTSAM 4.3.0's PseudorangeFactor = |p - s| + omega/c (x_s y_r - y_s x_r) + c (dt - dt_s) - rho."""
    sat = _sat(60, 30)
    f = gtsam.PseudorangeFactor(0, 1, 2.1e7, sat, 1e-4, gtsam.noiseModel.Unit.Create(1))
    err = float(f.evaluateError(RX, 2e-4)[0])
    sagnac = OMEGA_E_GPS / C * (sat[0] * RX[1] - sat[1] * RX[0])
    expect = np.linalg.norm(RX - sat) + sagnac + C * (2e-4 - 1e-4) - 2.1e7
    assert abs(sagnac) > 1.0  # tens of metres: it matters
    assert err == pytest.approx(expect, abs=1e-6)
    assert F.gtsam_applies_sagnac() is True


@pytest.mark.parametrize(("az", "el"), [(0, 15), (45, 40), (130, 70), (200, 25), (300, 85)])
def test_pseudorange_factor_reproduces_the_inputs_model(az: float, el: float) -> None:
    """With the satellite in the reception frame (inputs.PseudorangeObs), the factor built by
    pseudorange_factors gives rho - (|p - s_rx| + c (dt - dt_s)) to < 1 mm."""
    s_tx = _sat(az, el)
    tau = np.linalg.norm(s_tx - RX) / C
    s_rx = _rotate_z(s_tx, OMEGA_E_GPS * tau)
    clock, sat_clock = 1.2e-4, -3e-5
    rho = float(np.linalg.norm(RX - s_rx)) + C * (clock - sat_clock) + 7.5  # 7.5 m of "noise"
    approx = RX + np.array([300.0, -200.0, 150.0])  # the initial guess, not the truth
    (f,) = F.pseudorange_factors(1, [2], [rho], s_rx[None, :], [sat_clock], [3.0], approx)
    err = float(f.unwhitenedError(_values({1: RX, 2: clock}))[0])
    assert err == pytest.approx(-7.5, abs=1e-3)


def test_pseudorange_factor_jacobian_matches_finite_differences() -> None:
    sigma = 2.5
    (f,) = F.pseudorange_factors(1, [2], [2.3e7], _sat(120, 35)[None, :], [1e-5], [sigma], RX)
    entries: dict[int, np.ndarray | float] = {1: RX + np.array([3.0, -2.0, 1.0]), 2: 1e-4}
    num = _numeric_jacobian(f, entries, {1: 1.0, 2: 1e-8})
    ana = _analytic_jacobian(f, entries, sigma)
    np.testing.assert_allclose(ana[:, :3], num[:, :3], atol=1e-7)
    # the clock is in seconds: d(error)/d(clock) = c
    assert ana[0, 3] == pytest.approx(C, rel=1e-9)
    assert num[0, 3] == pytest.approx(C, rel=1e-6)


# ---------------------------------------------------------------------------------------------
# plane (native: a prior on a point of the plane with a rank-1 square-root information)


def _plane_residual_m(f: gtsam.NoiseModelFactor, p: np.ndarray, sigma: float) -> np.ndarray:
    """The plane factor's whitened error times sigma: (n.p + d, 0, 0) in metres."""
    return np.asarray(f.whitenedError(_values({f.keys()[0]: p}))) * sigma


def test_plane_factor_error_sign_and_value() -> None:
    up = ENU[2]
    on_plane = RX.copy()
    plane = PlaneObs(up, -float(up @ on_plane), 0.1)
    f = F.plane_factor(7, plane)
    above = on_plane + 1.0 * up + 5.0 * ENU[0]  # 1 m above, moved along the plane
    below = on_plane - 0.25 * up
    np.testing.assert_allclose(_plane_residual_m(f, above, 0.1), [1.0, 0.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(_plane_residual_m(f, below, 0.1), [-0.25, 0.0, 0.0], atol=1e-6)
    assert _plane_residual_m(f, above, 0.1)[0] == pytest.approx(plane.error(above), abs=1e-9)
    # cost 0.5 (e / sigma)^2 = 0.5 * 100 for 1 m at sigma 0.1 m
    assert f.error(_values({7: above})) == pytest.approx(50.0, rel=1e-6)


@pytest.mark.parametrize("axis_aligned", [False, True])
def test_plane_factor_jacobian_is_the_normal(axis_aligned: bool) -> None:
    """Linearised: one row n^T / sigma (finite differences agree), the other two rows zero."""
    if axis_aligned:  # R is diagonal: must stay rank 1, with no division by its zeros
        n = np.array([1.0, 0.0, 0.0])
    else:
        n = np.array([0.03, -0.02, 1.0])
        n /= np.linalg.norm(n)
        n = ENU.T @ n
    sigma = 0.2
    plane = PlaneObs(n, -float(n @ RX) - 1.7, sigma)
    f = F.plane_factor(3, plane)
    p = RX + np.array([1.0, 2.0, 3.0])
    a, b = f.linearize(_values({3: p})).jacobian()
    step = 0.5
    num = np.column_stack(
        [
            (_plane_residual_m(f, p + h, sigma) - _plane_residual_m(f, p - h, sigma)) / (2 * step)
            for h in step * np.eye(3)
        ]
    )
    np.testing.assert_allclose(np.asarray(a) * sigma, num, atol=1e-6)
    np.testing.assert_allclose(np.asarray(a)[0] * sigma, n, atol=1e-12)
    np.testing.assert_allclose(np.asarray(a)[1:], 0.0, atol=0.0)
    assert -float(b[0]) * sigma == pytest.approx(plane.error(p), abs=1e-9)


def test_plane_factor_constrains_only_the_normal_direction() -> None:
    """With a prior of 1 m per axis, the plane at 0.1 m shrinks the marginal along n only."""
    n = ENU[2]
    g = gtsam.NonlinearFactorGraph()
    g.add(F.plane_factor(1, PlaneObs(n, -float(n @ RX), 0.1)))
    g.add(F.position_prior(1, RX, np.eye(3)))
    cov = gtsam.Marginals(g, _values({1: RX})).marginalCovariance(1)
    var_n = 1.0 / (1.0 + 1.0 / 0.1**2)
    np.testing.assert_allclose(ENU @ cov @ ENU.T, np.diag([1.0, 1.0, var_n]), atol=1e-9)


def test_plane_factor_rejects_a_zero_normal() -> None:
    with pytest.raises(ValueError, match="unit vector"):
        F.plane_factor(1, PlaneObs(np.zeros(3), 0.0, 0.1))


# ---------------------------------------------------------------------------------------------
# range, between, clock, priors


def test_range_factor3_is_point3_to_point3_and_signed() -> None:
    a = RX
    b = RX + np.array([3.0, 4.0, 12.0])  # 13 m apart
    f = F.range_factor(1, 2, 12.5, 0.3)
    assert isinstance(f, gtsam.RangeFactor3)
    assert float(f.unwhitenedError(_values({1: a, 2: b}))[0]) == pytest.approx(0.5, abs=1e-9)
    entries: dict[int, np.ndarray | float] = {1: a, 2: b}
    np.testing.assert_allclose(
        _analytic_jacobian(f, entries, 0.3), _numeric_jacobian(f, entries, {1: 1e-3, 2: 1e-3}), atol=1e-6
    )
    # RangeFactor3D is the Pose3 -> Point3 variant: it cannot read two points
    g = gtsam.RangeFactor3D(1, 2, 13.0, F.isotropic(1, 0.3))
    with pytest.raises(RuntimeError):
        g.unwhitenedError(_values({1: a, 2: b}))


def test_displacement_factor_is_p2_minus_p1_minus_displacement() -> None:
    f = F.displacement_factor(1, 2, np.array([10.0, 0.0, -1.0]), 0.6)
    p1, p2 = RX, RX + np.array([10.5, 0.2, -1.0])
    np.testing.assert_allclose(f.unwhitenedError(_values({1: p1, 2: p2})), [0.5, 0.2, 0.0], atol=1e-8)
    entries: dict[int, np.ndarray | float] = {1: p1, 2: p2}
    np.testing.assert_allclose(
        _analytic_jacobian(f, entries, 0.6), _numeric_jacobian(f, entries, {1: 0.1, 2: 0.1}), atol=1e-6
    )


def test_clock_factor_works_in_seconds() -> None:
    sigma_m = F.clock_step_sigma_m(1.0, 0.0, 1.0)
    assert sigma_m == pytest.approx(1.0)
    assert F.clock_step_sigma_m(2.0, 300.0, 1.0) == pytest.approx(math.sqrt(2.0 + 600.0**2))
    f = F.clock_factor(1, 2, 50.0, sigma_m)  # the clock advanced 50 m (drift 50 m/s over 1 s)
    b1 = 1e-4
    b2 = b1 + 52.0 / C  # 2 m more than predicted
    err_s = float(f.unwhitenedError(_values({1: b1, 2: b2}))[0])
    assert err_s * C == pytest.approx(2.0, abs=1e-6)
    assert f.error(_values({1: b1, 2: b2})) == pytest.approx(0.5 * 4.0, rel=1e-6)


def test_clock_and_prior_jacobians_match_finite_differences() -> None:
    sigma_m = 2.0
    f = F.clock_factor(1, 2, 30.0, sigma_m)
    entries: dict[int, np.ndarray | float] = {1: 1e-4, 2: 1e-4 + 31.0 / C}
    num = _numeric_jacobian(f, entries, {1: 1e-8, 2: 1e-8})
    np.testing.assert_allclose(_analytic_jacobian(f, entries, sigma_m / C), num, atol=1e-6)
    np.testing.assert_allclose(num, [[-1.0, 1.0]], atol=1e-6)
    p = F.position_prior(3, RX, 4.0 * np.eye(3))
    e3: dict[int, np.ndarray | float] = {3: RX + np.array([1.0, -1.0, 2.0])}
    np.testing.assert_allclose(_analytic_jacobian(p, e3, 2.0), _numeric_jacobian(p, e3, {3: 0.1}), atol=1e-6)
    q = F.clock_prior(4, 1e-4, 1e-6)
    assert float(q.unwhitenedError(_values({4: 1e-4 + 2e-6}))[0]) == pytest.approx(2e-6, rel=1e-9)


def test_robust_kernels_downweight_large_residuals_only() -> None:
    sat = F.gtsam_satellite_positions(_sat(10, 50)[None, :], RX)[0]
    r0 = float(np.linalg.norm(RX - sat)) + OMEGA_E_GPS / C * (sat[0] * RX[1] - sat[1] * RX[0])
    vals_small = _values({1: RX, 2: 0.0})
    for kernel, k in (("huber", 1.345), ("cauchy", 2.385), ("dcs", 4.0)):
        robust = F.robust_isotropic(1, 3.0, kernel, k)
        plain = F.isotropic(1, 3.0)
        small_r = gtsam.PseudorangeFactor(1, 2, r0 + 1.5, sat, 0.0, robust)
        small_p = gtsam.PseudorangeFactor(1, 2, r0 + 1.5, sat, 0.0, plain)
        big_r = gtsam.PseudorangeFactor(1, 2, r0 + 60.0, sat, 0.0, robust)
        big_p = gtsam.PseudorangeFactor(1, 2, r0 + 60.0, sat, 0.0, plain)
        assert small_r.error(vals_small) == pytest.approx(small_p.error(vals_small), rel=0.15)
        assert big_r.error(vals_small) < 0.5 * big_p.error(vals_small)
    with pytest.raises(ValueError):
        F.robust_isotropic(1, 3.0, "tukey", 4.0)


def test_kernel_on_planes_and_links_leaves_small_errors_and_cuts_large_ones() -> None:
    """`robust_planes_links`: the plane factor and the displacement link take the kernel too (on the
    Mahalanobis length of the whole error), and only their large errors lose weight."""
    up = RX / np.linalg.norm(RX)
    plane = PlaneObs(up, -float(up @ RX), 0.5)
    near, far = _values({1: RX + 0.2 * up}), _values({1: RX + 10.0 * up})
    plain, robust = F.plane_factor(1, plane), F.plane_factor(1, plane, "huber", 1.345)
    assert robust.error(near) == pytest.approx(plain.error(near), rel=1e-9)
    assert robust.error(far) < 0.5 * plain.error(far)
    still = _values({1: RX, 2: RX})
    d_plain = F.displacement_factor(1, 2, 0.2 * up, 0.5)
    d_robust = F.displacement_factor(1, 2, 0.2 * up, 0.5, robust="dcs", robust_k=4.0)
    assert d_robust.error(still) == pytest.approx(d_plain.error(still), rel=1e-9)
    jump_plain = F.displacement_factor(1, 2, 10.0 * up, 0.5, RX, 0.2)
    jump_robust = F.displacement_factor(1, 2, 10.0 * up, 0.5, RX, 0.2, "dcs", 4.0)
    assert jump_robust.error(still) < 0.1 * jump_plain.error(still)


def test_floored_covariance_raises_small_eigenvalues_only() -> None:
    rot = np.linalg.qr(np.random.default_rng(0).normal(size=(3, 3)))[0]
    cov = rot @ np.diag([0.01, 4.0, 400.0]) @ rot.T
    out = F.floored_covariance(cov, 10.0)
    np.testing.assert_allclose(np.sort(np.linalg.eigvalsh(out)), [100.0, 100.0, 400.0], rtol=1e-9)
    np.testing.assert_allclose(F.floored_covariance(None, 3.0), 9.0 * np.eye(3))
    np.testing.assert_allclose(F.floored_covariance(np.full((3, 3), np.nan), 3.0), 9.0 * np.eye(3))


def test_position_prior_uses_the_full_covariance() -> None:
    cov = np.diag([1.0, 4.0, 100.0])
    f = F.position_prior(5, RX, cov)
    assert f.error(_values({5: RX + np.array([0.0, 0.0, 10.0])})) == pytest.approx(0.5, rel=1e-9)
    assert f.error(_values({5: RX + np.array([2.0, 0.0, 0.0])})) == pytest.approx(2.0, rel=1e-9)


# ---------------------------------------------------------------------------------------------
# keys


def test_keys_are_unique_and_decode() -> None:
    reg = KeyRegistry()
    seen: set[int] = set()
    for vid in ("a", "b", "c"):
        slot = reg.slot(vid)
        for step in (0, 1, 2**20, 2**32 - 1):
            ks = [position_key(slot, step), clock_key(slot, step, "G"), clock_key(slot, step, "C")]
            for k in ks:
                assert k not in seen
                seen.add(k)
            assert decode_key(ks[0]) == ("position", slot, step)
            assert decode_key(ks[1]) == ("clock-G", slot, step)
            assert decode_key(ks[2]) == ("clock-C", slot, step)
    assert reg.slot("b") == 1  # stable
    assert reg.vehicle(2) == "c"
    with pytest.raises(ValueError):
        position_key(0, 2**32)
    with pytest.raises(ValueError):
        clock_key(0, 0, "X")
