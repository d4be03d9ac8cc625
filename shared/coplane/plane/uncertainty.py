"""Covariance of a fitted road plane and the factor sigma it implies at the vehicle (docs/planes.md).

The plane factor constrains the antenna's height above the plane at the vehicle, not at the
centroid of the fitting points. Its honest 1-sigma there has three parts:

- the plane's offset at the centroid, which inherits the points' errors;
- the plane's tilt (the normal's two small rotations, along and across the road) times the lever
  arm from the centroid to the vehicle: points spread 40 m along the road but 2 m across it fix
  the grade well and the cross-slope poorly, so 2 m beside the points the plane is uncertain;
- the road's own departure from the plane at a new point (the fit residual, floored).

First-order total least squares: with the points' in-plane coordinates ``a_ik = (x_k - c) . e_i``
(``e_1, e_2`` the in-plane principal axes, ``lambda_i = sum_k a_ik^2 = s_i^2`` of the centred SVD)
and their errors ``eps_k`` along the normal, the height of the plane at in-plane coordinates
``a = (a_1, a_2)`` moves by ``sum_k w_k(a) eps_k`` with ``w_k(a) = 1/N + sum_i a_i a_ik / lambda_i``
(errors along the plane move the normal only to second order). So with ``C = cov(eps)``, the
covariance of (offset at the centroid, slope along e_1, slope along e_2) is ``G C G^T`` with rows
``1/N`` and ``a_ik / lambda_i``; with independent equal errors it is the textbook
``diag(sigma^2 / N, sigma^2 / lambda_1, sigma^2 / lambda_2)``.

``C`` (`point_error_covariance`) is each point's own vertical sigma from the fusion covariance,
fully correlated between positions of one vehicle (the correlation decays as ``exp(-|dt| / tau)``
with `PlaneConfig.point_error_correlation_s`, infinite by default), plus an independent scatter:
what the fit residual shows beyond those (`scatter_sigma_m`). The first part is what the residual
cannot see: if all of one vehicle's points are 1 m high, they fit a plane well, and it is 1 m high
on that vehicle's side. Treating a vehicle's points as one sample is the reasoning of
`detect.offset_sigma_m` (multipath and NLOS errors last seconds, and the points within 50 m of a
vehicle span seconds of its track); at the centroid, with equal point counts per vehicle, the two
agree.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from coplane.plane.config import PlaneConfig
from coplane.plane.detect import RoadPlane
from coplane.plane.fit import centred_svd
from coplane.typing import Mat, Vec


@dataclass(frozen=True, eq=False)
class PlaneUncertainty:
    """A plane's first-order covariance and the sigma of its height at any point."""

    centroid: Vec  # of the fitted points, ECEF
    axes: Vec  # (2, 3) in-plane principal axes: e1 along the largest spread, e2 across it
    covariance: Mat  # (3, 3) of (height at the centroid m, slope along e1 rad, slope along e2 rad)
    road_sigma_m: float  # the road's own departure from the plane at a new point

    @property
    def offset_sigma_m(self) -> float:
        """1-sigma of the plane's height at the centroid of its points."""
        return math.sqrt(max(float(self.covariance[0, 0]), 0.0))

    @property
    def tilt_sigma_rad(self) -> float:
        """1-sigma of the normal's direction about its least-determined axis (the larger of the two)."""
        return math.sqrt(max(float(np.linalg.eigvalsh(self.covariance[1:, 1:])[-1]), 0.0))

    def lever(self, q: ArrayLike) -> Vec:
        """(1, a1, a2): the map from (offset, slope1, slope2) to the plane's height at `q`."""
        a = self.axes @ (np.asarray(q, dtype=float) - self.centroid)
        return np.array([1.0, float(a[0]), float(a[1])])

    def plane_sigma_at(self, q: ArrayLike) -> float:
        """1-sigma of the fitted plane's height at `q` (its in-plane position; height is ignored)."""
        h = self.lever(q)
        return math.sqrt(max(float(h @ self.covariance @ h), 0.0))

    def sigma_at(self, q: ArrayLike) -> float:
        """The plane factor's sigma at `q`: plane uncertainty there and the road's own departure."""
        return math.hypot(self.road_sigma_m, self.plane_sigma_at(q))


def point_error_covariance(
    sigmas_up_m: ArrayLike,
    vehicle_ids: Sequence[str],
    times_s: ArrayLike,
    scatter_sigma_m: float,
    correlation_s: float = math.inf,
) -> Mat:
    """(N, N) covariance of the points' errors along the normal.

    ``scatter^2 I`` (independent) plus ``sigma_k sigma_l rho_kl`` for points of the same vehicle,
    ``rho_kl = exp(-|t_k - t_l| / correlation_s)`` (1 when infinite). Unknown sigmas (NaN) take the
    RMS of the known ones (0 if none is known), so a point without a covariance is not exact.
    """
    s = np.asarray(sigmas_up_m, dtype=float).reshape(-1)
    t = np.asarray(times_s, dtype=float).reshape(-1)
    n = s.shape[0]
    if len(vehicle_ids) != n or t.shape[0] != n:
        raise ValueError(f"{n} sigmas, {len(vehicle_ids)} vehicle ids and {t.shape[0]} times differ")
    known = np.isfinite(s)
    fill = float(np.sqrt(np.mean(s[known] ** 2))) if known.any() else 0.0
    s = np.where(known, s, fill)
    ids = np.unique(np.asarray(vehicle_ids, dtype=object), return_inverse=True)[1].reshape(-1)
    rho = (ids[:, None] == ids[None, :]).astype(float)
    if math.isfinite(correlation_s):
        rho *= np.exp(-np.abs(t[:, None] - t[None, :]) / correlation_s)
    return np.asarray(rho * np.outer(s, s) + scatter_sigma_m**2 * np.eye(n), dtype=float)


def _influence(points: Vec) -> tuple[Vec, Vec, Mat]:
    """Centroid, in-plane axes (2, 3) and G (3, N): how each point's error moves offset and slopes."""
    centroid, s, vt = centred_svd(points)
    axes = np.asarray(vt[:2], dtype=float)
    a = (points - centroid) @ axes.T  # (N, 2) in-plane coordinates
    lam = np.maximum(s[:2] ** 2, 1e-12)
    n = points.shape[0]
    return centroid, axes, np.vstack([np.full(n, 1.0 / n), a[:, 0] / lam[0], a[:, 1] / lam[1]])


def fit_covariance(points: ArrayLike, error_covariance: ArrayLike) -> tuple[Vec, Vec, Mat]:
    """Centroid, in-plane axes (2, 3) and covariance (3, 3) of the TLS plane through `points`.

    `error_covariance` (N, N) is that of the points' errors along the normal. The axes come from
    the same centred SVD as `fit.fit_plane`, so they belong to the plane that was fitted.
    """
    p = np.asarray(points, dtype=float).reshape(-1, 3)
    c_err = np.asarray(error_covariance, dtype=float)
    n = p.shape[0]
    if n < 3 or c_err.shape != (n, n):
        raise ValueError(f"need >= 3 points and an ({n}, {n}) covariance, got {c_err.shape}")
    centroid, axes, g = _influence(p)
    return centroid, axes, np.asarray(g @ c_err @ g.T, dtype=float)


def scatter_sigma_m(points: ArrayLike, rss_m2: float, correlated: ArrayLike) -> float:
    """The independent per-point scatter left once the points' own errors are accounted for.

    The residual sum of squares of a plane fit to N points with error covariance
    ``s^2 I + D`` has expectation ``s^2 (N - 3) + tr((I - H) D)`` (H the fit's hat matrix): part
    of the vehicles' own errors shows up in the residuals too. Solving for ``s^2`` (method of
    moments, floored at 0) keeps that part from being counted twice.
    """
    p = np.asarray(points, dtype=float).reshape(-1, 3)
    d = np.asarray(correlated, dtype=float)
    n = p.shape[0]
    centroid, axes, g = _influence(p)
    x = np.column_stack([np.ones(n), (p - centroid) @ axes.T])  # H = X G
    seen = float(np.trace(d) - np.einsum("ij,ji->", x @ g, d))
    return math.sqrt(max(rss_m2 - seen, 0.0) / max(n - 3, 1))


def plane_uncertainty(
    plane: RoadPlane,
    sigmas_up_m: ArrayLike,
    vehicle_ids: Sequence[str],
    times_s: ArrayLike,
    config: PlaneConfig,
) -> PlaneUncertainty:
    """The covariance of an available `plane` from the records of the points it was offered.

    `sigmas_up_m`, `vehicle_ids`, `times_s` describe all points passed to `construct_plane`
    (`HistorySample`); the ones fault exclusion removed are dropped with `plane.used_index`. The
    independent scatter is what the fit residual leaves after the points' own errors
    (`scatter_sigma_m`).
    """
    if not plane.available:
        raise ValueError(f"no covariance for an unavailable plane ({plane.reason})")
    idx = plane.used_index
    pts = plane.points_used
    ids = [vehicle_ids[i] for i in idx.tolist()]
    own = point_error_covariance(
        np.asarray(sigmas_up_m, dtype=float)[idx],
        ids,
        np.asarray(times_s, dtype=float)[idx],
        0.0,
        config.point_error_correlation_s,
    )
    scatter = scatter_sigma_m(pts, pts.shape[0] * plane.residual_rms_m**2, own)
    centroid, axes, cov = fit_covariance(pts, own + scatter**2 * np.eye(pts.shape[0]))
    return PlaneUncertainty(centroid=centroid, axes=axes, covariance=cov, road_sigma_m=plane.sigma_m)
