"""SVD plane fit (paper eqs. 6-11, 15), upward orientation, antenna translation (eqs. 12-13, 24)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from coplane.geo import enu_rotation, geodetic_to_ecef, up_vector
from coplane.plane.fit import (
    Degenerate,
    PlaneFit,
    antenna_offset,
    constraint_error,
    fit_plane,
    plane_through_three,
)

Z = np.array([0.0, 0.0, 1.0])


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    """Angle between two lines (sign-free), accurate near 0 unlike acos of the dot product."""
    return math.atan2(float(np.linalg.norm(np.cross(a, b))), abs(float(a @ b)))


def _fit(points: np.ndarray, up: np.ndarray | None = None) -> PlaneFit:
    f = fit_plane(points, up)
    assert isinstance(f, PlaneFit), f
    return f


# -- hand-computed cases ---------------------------------------------------------------------


def test_tilted_plane_hand_computed() -> None:
    # z = x/2 + 3 in a local frame: normal (-1, 0, 2)/sqrt(5), d = -6/sqrt(5).
    pts = np.array([[0, 0, 3], [2, 0, 4], [0, 2, 3], [2, 2, 4]], dtype=float)
    f = _fit(pts, Z)
    np.testing.assert_allclose(f.normal, np.array([-1.0, 0.0, 2.0]) / math.sqrt(5), atol=1e-12)
    assert f.d == pytest.approx(-6 / math.sqrt(5), abs=1e-12)
    np.testing.assert_allclose(f.centroid, [1.0, 1.0, 3.5], atol=1e-12)
    # centred rows (+-1, +-1, +-0.5): A^T A has eigenvalues 5 (along (2,0,1)), 4 (y) and 0.
    np.testing.assert_allclose(f.singular_values, [math.sqrt(5), 2.0, 0.0], atol=1e-12)
    assert f.conditioning == math.inf
    assert f.tilt_deg == pytest.approx(math.degrees(math.atan(0.5)), abs=1e-9)
    np.testing.assert_allclose(f.distances(pts), 0.0, atol=1e-12)
    # a point 1 m along the normal from the plane has signed distance +1 (above)
    assert f.signed_distances(pts[:1] + f.normal)[0] == pytest.approx(1.0, abs=1e-12)


@pytest.mark.parametrize("e", [0.1, 0.4])
def test_saddle_residuals_hand_computed(e: float) -> None:
    # (+-1, +-1, e*x*y) + 7: A^T A = diag(4, 4, 4e^2), so n = z, d = -7 and every residual is e.
    pts = np.array([[1, 1, e], [-1, -1, e], [1, -1, -e], [-1, 1, -e]], dtype=float) + np.array([0, 0, 7.0])
    f = _fit(pts, Z)
    np.testing.assert_allclose(f.normal, Z, atol=1e-12)
    assert f.d == pytest.approx(-7.0, abs=1e-12)
    np.testing.assert_allclose(f.distances(pts), e, atol=1e-12)
    np.testing.assert_allclose(f.signed_distances(pts), [e, e, -e, -e], atol=1e-12)
    np.testing.assert_allclose(f.singular_values, [2.0, 2.0, 2 * e], atol=1e-12)
    assert f.conditioning == pytest.approx(1 / e)


def test_normal_is_oriented_by_up_not_by_svd_sign() -> None:
    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.0]])
    assert _fit(pts, Z).normal @ Z == pytest.approx(1.0)
    assert _fit(pts, -Z).normal @ Z == pytest.approx(-1.0)
    assert _fit(pts[::-1].copy(), Z).normal @ Z == pytest.approx(1.0)


# -- degenerate input --------------------------------------------------------------------------


def test_too_few_and_coincident_points_are_degenerate() -> None:
    p0 = geodetic_to_ecef(0.7, 2.0, 40.0)
    for pts in (np.empty((0, 3)), p0[None], np.stack([p0, p0 + 1.0]), np.stack([p0] * 5)):
        f = fit_plane(pts)
        assert isinstance(f, Degenerate)
        assert f.reason.startswith("degenerate")
    assert "coincident" in fit_plane(np.stack([p0] * 5)).reason  # type: ignore[union-attr]


@settings(max_examples=40, deadline=None)
@given(
    lat=st.floats(-1.4, 1.4),
    lon=st.floats(-3.1, 3.1),
    az=st.floats(0.0, 2 * math.pi),
    el=st.floats(-1.5, 1.5),
    n=st.integers(3, 30),
)
def test_collinear_points_at_earth_scale_are_degenerate(
    lat: float, lon: float, az: float, el: float, n: int
) -> None:
    base = geodetic_to_ecef(lat, lon, 10.0)
    direction = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
    pts = base + np.linspace(-50, 50, n)[:, None] * direction
    f = fit_plane(pts)
    assert isinstance(f, Degenerate)
    assert "collinear" in f.reason
    assert plane_through_three(pts[[0, n // 2, -1]]) is None


def test_non_finite_points_rejected() -> None:
    with pytest.raises(ValueError, match="NaN"):
        fit_plane(np.array([[0, 0, 0], [1, 0, 0], [0, 1, math.nan]]))
    with pytest.raises(ValueError, match="shape"):
        fit_plane([1.0, 2.0, 3.0])


# -- exact planes of any orientation at Earth scale -------------------------------------------


def _random_plane(lat: float, lon: float, h: float, normal: np.ndarray, n: int, rng: np.random.Generator):
    """Points of the plane through a point at geodetic (lat, lon, h) with the given unit normal."""
    base = geodetic_to_ecef(lat, lon, h)
    helper = np.array([1.0, 0, 0]) if abs(normal[0]) < 0.9 else np.array([0, 1.0, 0])
    e1 = np.cross(normal, helper)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(normal, e1)
    ab = rng.uniform(-50, 50, (n, 2))
    return base, base + ab[:, :1] * e1 + ab[:, 1:] * e2


unit_vectors = st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1)).filter(
    lambda v: 0.1 < math.sqrt(v[0] ** 2 + v[1] ** 2 + v[2] ** 2) <= 1.0
)


@settings(max_examples=60, deadline=None)
@given(
    lat=st.floats(-1.5, 1.5),
    lon=st.floats(-3.14, 3.14),
    h=st.floats(-100.0, 4000.0),
    v=unit_vectors,
    seed=st.integers(0, 2**32 - 1),
)
def test_exact_plane_any_orientation(
    lat: float, lon: float, h: float, v: tuple[float, float, float], seed: int
) -> None:
    normal = np.array(v) / np.linalg.norm(v)
    rng = np.random.default_rng(seed)
    base, pts = _random_plane(lat, lon, h, normal, 20, rng)
    f = _fit(pts)
    assert _angle(f.normal, normal) < 1e-9
    sign = 1.0 if f.normal @ normal > 0 else -1.0
    assert f.d == pytest.approx(-sign * float(normal @ base), abs=1e-3)  # d within a millimetre
    assert abs(np.linalg.norm(f.normal) - 1.0) < 1e-12
    assert f.normal @ up_vector(f.centroid) >= 0.0  # always oriented upward
    assert f.distances(pts).max() < 1e-6


@settings(max_examples=60, deadline=None)
@given(
    lat=st.floats(-1.5, 1.5),
    lon=st.floats(-3.14, 3.14),
    tilt=st.floats(0.0, math.radians(60)),
    azimuth=st.floats(0.0, 2 * math.pi),
    noise=st.floats(0.0, 1e-3),
    seed=st.integers(0, 2**32 - 1),
)
def test_near_horizontal_plane_recovered_upward_with_noise(
    lat: float, lon: float, tilt: float, azimuth: float, noise: float, seed: int
) -> None:
    # normal tilted from local up by `tilt` towards `azimuth`, expressed in ECEF
    enu_n = np.array([math.sin(tilt) * math.sin(azimuth), math.sin(tilt) * math.cos(azimuth), math.cos(tilt)])
    normal = enu_rotation(lat, lon).T @ enu_n
    rng = np.random.default_rng(seed)
    _, pts = _random_plane(lat, lon, 50.0, normal, 20, rng)
    pts = pts + rng.normal(0.0, noise, pts.shape) if noise > 0 else pts
    f = _fit(pts)
    assert float(f.normal @ normal) > 0.0  # the same, upward, sign as the truth
    assert _angle(f.normal, normal) < 1e-4
    assert f.tilt_deg == pytest.approx(math.degrees(tilt), abs=0.2)  # up at centroid vs at base
    # d is not compared under noise: a 1e-6 rad normal error moves d by up to 6 m through the
    # 6.4e6 m lever arm. The plane itself must agree with the truth over the whole patch:
    true_pts = pts if noise == 0 else _random_plane(lat, lon, 50.0, normal, 50, rng)[1]
    assert f.distances(true_pts).max() < 5e-3


# -- antenna translation (eqs. 12-13) and the factor form (eqs. 22-24) -------------------------


@settings(max_examples=40, deadline=None)
@given(
    lat=st.floats(-1.5, 1.5),
    lon=st.floats(-3.14, 3.14),
    tilt=st.floats(0.0, math.radians(30)),
    azimuth=st.floats(0.0, 2 * math.pi),
    h_ant=st.floats(0.0, 5.0),
    seed=st.integers(0, 2**32 - 1),
)
def test_antenna_plane_is_h_above_road(
    lat: float, lon: float, tilt: float, azimuth: float, h_ant: float, seed: int
) -> None:
    enu_n = np.array([math.sin(tilt) * math.sin(azimuth), math.sin(tilt) * math.cos(azimuth), math.cos(tilt)])
    rng = np.random.default_rng(seed)
    _, pts = _random_plane(lat, lon, 20.0, enu_rotation(lat, lon).T @ enu_n, 20, rng)
    road = _fit(pts)
    ant = road.translated(h_ant)
    assert ant.d == pytest.approx(antenna_offset(road.d, h_ant)) and ant.d == road.d - h_ant
    for p_road in pts[:5]:
        p_ant = p_road + h_ant * road.normal
        assert ant.constraint_error(p_ant) == pytest.approx(0.0, abs=1e-6)  # on the antenna plane
        assert ant.constraint_error(p_road) == pytest.approx(-h_ant, abs=1e-6)  # h below it
        assert road.constraint_error(p_ant) == pytest.approx(h_ant, abs=1e-6)
        # eq. (24) literally: P'^D - p . u_PC with u_PC = -n
        assert constraint_error(ant.normal, ant.d, p_ant) == pytest.approx(
            ant.d - float(p_ant @ ant.u_pc), abs=1e-9
        )


def _eq13(p_d: float, h: float) -> float:
    """The paper's sign rule, used here only to show where it fails."""
    return p_d + h if p_d >= 0 else p_d - h


def test_eq13_sign_rule_agrees_in_ecef_but_fails_with_origin_above_road() -> None:
    h = 1.6
    # ECEF, level road: either sign of the SVD normal gives the right plane with eq. (13),
    # because the Earth's centre (the origin) lies below every road.
    lat, lon = 0.6, 2.0
    up = up_vector(geodetic_to_ecef(lat, lon, 0.0))
    e, n = enu_rotation(lat, lon)[0], enu_rotation(lat, lon)[1]
    base = geodetic_to_ecef(lat, lon, 30.0)
    pts = base + np.array([[x * 10, y * 3.5, 0] for x in range(-3, 4) for y in (0, 1)]) @ np.stack([e, n, up])
    f = _fit(pts)
    antenna_point = base + h * f.normal
    for sign in (1.0, -1.0):
        nn, dd = sign * f.normal, sign * f.d
        assert float(nn @ antenna_point) + _eq13(dd, h) == pytest.approx(0.0, abs=1e-6)
    # local frame whose origin is 10 m ABOVE the road (z = -10): P^D = +10 >= 0, so eq. (13)
    # moves the plane DOWN to z = -11.6; translating along the upward normal gives z = -8.4.
    local = np.array([[x, y, -10.0] for x in (-20.0, 0.0, 20.0) for y in (-2.0, 2.0)])
    g = _fit(local, Z)
    assert g.d == pytest.approx(10.0)
    assert float(Z @ [0, 0, -10 + h]) + antenna_offset(g.d, h) == pytest.approx(0.0)
    assert float(Z @ [0, 0, -10 + h]) + _eq13(g.d, h) == pytest.approx(2 * h)  # eq. 13: 2h off
