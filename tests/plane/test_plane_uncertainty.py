"""The fitted plane's covariance (coplane.plane.uncertainty) against Monte-Carlo, lever arm, one lane."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from coplane.geo import enu_to_ecef, geodetic_to_ecef, up_vector
from coplane.plane import PlaneConfig, construct_plane
from coplane.plane.fit import PlaneFit, fit_plane
from coplane.plane.uncertainty import (
    PlaneUncertainty,
    fit_covariance,
    plane_uncertainty,
    point_error_covariance,
    scatter_sigma_m,
)

REF = geodetic_to_ecef(math.radians(39.98), math.radians(116.31), 50.0)
UP_ENU = np.array([0.0, 0.0, 1.0])
N = 20
IDS = tuple(f"v{i % 4}" for i in range(N))  # 4 vehicles, 5 points each


def patch(g: np.random.Generator, width: float = 8.0, length: float = 60.0) -> np.ndarray:
    """N road points (ENU, on z = 0) spread `width` across and `length` along north."""
    return np.c_[g.uniform(-width / 2, width / 2, N), g.uniform(-length / 2, length / 2, N), np.zeros(N)]


def model(points: np.ndarray, sigma_up: float, scatter: float) -> PlaneUncertainty:
    c_err = point_error_covariance(np.full(N, sigma_up), IDS, np.zeros(N), scatter)
    c, axes, cov = fit_covariance(points, c_err)
    return PlaneUncertainty(c, axes, cov, road_sigma_m=0.0)


def monte_carlo(
    points: np.ndarray, queries: list[np.ndarray], sigma_up: float, scatter: float, trials: int = 3000
) -> np.ndarray:
    """Empirical std of the fitted plane's height at each query: per-vehicle errors plus scatter."""
    g = np.random.default_rng(7)
    vid = np.array([int(v[1:]) for v in IDS])
    heights = np.empty((trials, len(queries)))
    for k in range(trials):
        noisy = points.copy()
        noisy[:, 2] += g.normal(0.0, sigma_up, 4)[vid] + g.normal(0.0, scatter, N)
        f = fit_plane(noisy, UP_ENU)
        assert isinstance(f, PlaneFit)
        heights[k] = [-float((q - f.centroid) @ f.normal) for q in queries]
    return np.asarray(heights.std(axis=0))


@pytest.mark.parametrize(("sigma_up", "scatter"), [(0.0, 0.5), (1.0, 0.2), (0.5, 0.5)])
def test_covariance_matches_monte_carlo(sigma_up: float, scatter: float) -> None:
    """Plane height sigma at the centroid, along the road, across it and both: within 15 % of MC."""
    pts = patch(np.random.default_rng(3))
    queries = [np.array(q) for q in ([0, 0, 0], [0, 25, 1.6], [4, 0, 1.6], [-3, -30, 1.6])]
    queries = [q + np.r_[pts[:, :2].mean(axis=0), 0.0] for q in queries]
    u = model(pts, sigma_up, scatter)
    mc = monte_carlo(pts, queries, sigma_up, scatter)
    pred = np.array([u.plane_sigma_at(q) for q in queries])
    np.testing.assert_allclose(pred, mc, rtol=0.15)


@pytest.mark.parametrize(("sigma_up", "scatter"), [(1.0, 0.2), (0.0, 0.5)])
def test_estimated_scatter_keeps_the_prediction_within_15_percent(sigma_up: float, scatter: float) -> None:
    """As the step runs it: the scatter estimated from each fit's residual, not known (RMS over fits)."""
    pts = patch(np.random.default_rng(3))
    q = np.r_[pts[:, :2].mean(axis=0), 0.0] + [4.0, 25.0, 1.6]
    own = point_error_covariance(np.full(N, sigma_up), IDS, np.zeros(N), 0.0)
    g = np.random.default_rng(11)
    vid = np.array([int(v[1:]) for v in IDS])
    heights, var = [], []
    for _ in range(2000):
        noisy = pts.copy()
        noisy[:, 2] += g.normal(0.0, sigma_up, 4)[vid] + g.normal(0.0, scatter, N)
        f = fit_plane(noisy, UP_ENU)
        assert isinstance(f, PlaneFit)
        heights.append(-float((q - f.centroid) @ f.normal))
        r = f.signed_distances(noisy)
        s_hat = scatter_sigma_m(noisy, float(r @ r), own)
        c, axes, cov = fit_covariance(noisy, own + s_hat**2 * np.eye(N))
        var.append(PlaneUncertainty(c, axes, cov, 0.0).plane_sigma_at(q) ** 2)
    assert math.sqrt(np.mean(var)) == pytest.approx(np.std(heights), rel=0.15)


def test_scatter_is_what_the_residual_leaves_after_the_points_own_errors() -> None:
    """No own errors: the usual sqrt(RSS / (N - 3)); own errors explaining it all: 0."""
    pts = patch(np.random.default_rng(9))
    assert scatter_sigma_m(pts, 17.0, np.zeros((N, N))) == pytest.approx(1.0)
    own = point_error_covariance(np.full(N, 1.0), IDS, np.zeros(N), 0.0)
    assert scatter_sigma_m(pts, 1.0, own) == 0.0
    assert scatter_sigma_m(pts, 100.0, own) < math.sqrt(100.0 / 17)


def test_independent_equal_errors_give_the_textbook_covariance() -> None:
    """Every point its own vehicle, equal sigma: diag(s^2/N, s^2/lambda1, s^2/lambda2)."""
    pts = patch(np.random.default_rng(4))
    ids = [f"v{i}" for i in range(N)]
    c_err = point_error_covariance(np.full(N, 0.3), ids, np.zeros(N), 0.4)
    _, _, cov = fit_covariance(pts, c_err)
    s = np.linalg.svd(pts - pts.mean(axis=0), compute_uv=False)
    np.testing.assert_allclose(np.diag(cov), 0.25 * np.array([1 / N, 1 / s[0] ** 2, 1 / s[1] ** 2]))
    np.testing.assert_allclose(cov - np.diag(np.diag(cov)), 0.0, atol=1e-15)


def test_sigma_grows_with_the_lever_arm() -> None:
    """sigma(t) = sqrt(sigma_c^2 + t^2 var_tilt) along each axis, increasing away from the centroid."""
    u = model(patch(np.random.default_rng(5)), 0.5, 0.2)
    for i in (0, 1):
        e = u.axes[i]
        sig = [u.plane_sigma_at(u.centroid + t * e) for t in (0.0, 5.0, 10.0, 20.0, 40.0)]
        assert all(b > a for a, b in itertools.pairwise(sig))
        want = [
            math.sqrt(
                u.covariance[0, 0] + 2 * t * u.covariance[0, 1 + i] + t * t * u.covariance[1 + i, 1 + i]
            )
            for t in (0.0, 5.0, 10.0, 20.0, 40.0)
        ]
        np.testing.assert_allclose(sig, want, rtol=1e-9)
    assert u.plane_sigma_at(u.centroid) == pytest.approx(u.offset_sigma_m)
    # height above the plane does not matter, only the in-plane position
    n = np.cross(u.axes[0], u.axes[1])
    assert u.plane_sigma_at(u.centroid + 7.0 * n) == pytest.approx(u.offset_sigma_m)


def test_one_lane_strip_has_a_large_cross_slope_sigma() -> None:
    """Points of one lane (0.6 m wide, 80 m long): the cross-slope is nearly free, the grade is not."""
    g = np.random.default_rng(6)
    pts = patch(g, width=0.6, length=80.0)
    u = model(pts, 0.5, 0.2)
    assert abs(u.axes[0][1]) == pytest.approx(1.0, abs=0.01)  # e1 along the road (north)
    slope_along, slope_across = math.sqrt(u.covariance[1, 1]), math.sqrt(u.covariance[2, 2])
    assert slope_across > 0.2  # rad: the vehicles' errors over a 0.6 m lateral spread
    assert slope_along < 0.02
    assert u.tilt_sigma_rad == pytest.approx(slope_across, rel=0.01)
    beside = u.plane_sigma_at(u.centroid + 3.5 * u.axes[1])  # the next lane
    ahead = u.plane_sigma_at(u.centroid + 3.5 * u.axes[0])
    assert beside > 1.0 and ahead < 0.4
    # two lanes 3.5 m apart (two vehicles in each): the cross-slope is far better determined
    two = pts.copy()
    two[::2, 0] += 3.5
    assert math.sqrt(model(two, 0.5, 0.2).covariance[2, 2]) < 0.5 * slope_across


def test_point_error_covariance() -> None:
    """Per-vehicle blocks of sigma_k sigma_l (decaying with time if asked) plus the scatter."""
    c = point_error_covariance([1.0, 2.0, 0.5, math.nan], ["a", "a", "b", "b"], [0, 10, 0, 5], 0.1)
    assert c[0, 1] == pytest.approx(2.0) and c[0, 2] == 0.0
    assert c[0, 0] == pytest.approx(1.01)
    fill = math.sqrt((1 + 4 + 0.25) / 3)  # unknown sigma: the RMS of the known ones
    assert c[3, 3] == pytest.approx(fill**2 + 0.01) and c[2, 3] == pytest.approx(0.5 * fill)
    d = point_error_covariance([1.0, 2.0], ["a", "a"], [0, 10], 0.0, correlation_s=10.0)
    assert d[0, 1] == pytest.approx(2.0 * math.exp(-1.0))
    assert np.all(point_error_covariance([math.nan] * 2, ["a", "b"], [0, 0], 0.0) == 0.0)
    with pytest.raises(ValueError, match="differ"):
        point_error_covariance([1.0], ["a", "b"], [0.0], 0.0)


def test_plane_uncertainty_of_a_road_plane_uses_only_the_inliers() -> None:
    """After fault exclusion the covariance is that of the used points; an outlier's record is dropped."""
    g = np.random.default_rng(8)
    enu = patch(g)
    enu[:, 2] += g.normal(0.0, 0.1, N)
    enu[3, 2] += 30.0
    plane = construct_plane(enu_to_ecef(enu, REF), 1.6, PlaneConfig(), g)
    assert plane.status.value == "available-after-fe" and 3 not in plane.used_index.tolist()
    sig = np.full(N, 0.4)
    sig[3] = 50.0  # would dominate if it were kept
    u = plane_uncertainty(plane, sig, IDS, np.zeros(N), PlaneConfig())
    assert u.offset_sigma_m < 0.4
    np.testing.assert_allclose(u.centroid, plane.centroid, atol=1e-6)
    up = up_vector(REF)
    assert u.axes @ up == pytest.approx(np.zeros(2), abs=0.05)  # in-plane axes: near horizontal
    assert u.sigma_at(u.centroid) == pytest.approx(math.hypot(plane.sigma_m, u.offset_sigma_m))
    unavailable = construct_plane(enu_to_ecef(enu[:5], REF), 1.6, PlaneConfig(), g)
    with pytest.raises(ValueError, match="unavailable"):
        plane_uncertainty(unavailable, sig[:5], IDS[:5], np.zeros(5), PlaneConfig())


def test_config_validates_the_sigma_model() -> None:
    assert PlaneConfig().sigma_model == "covariance"
    assert PlaneConfig().point_error_correlation_s == math.inf
    with pytest.raises(ValueError, match="sigma_model"):
        PlaneConfig(sigma_model="exact")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="point_error_correlation_s"):
        PlaneConfig(point_error_correlation_s=0.0)
    with pytest.raises(ValueError, match="point_error_correlation_s"):
        PlaneConfig(point_error_correlation_s=math.nan)
