"""Plane availability detection (eqs. 14-16) and RANSAC fault exclusion (Algorithm 1).

Flow (paper Fig. 3): fit all fitting points -> detect -> if it fails, RANSAC keeps the largest
consensus set -> re-fit on it -> detect again -> unavailable if it still fails.

Detection here is eq. (16) (max residual <= T_f and N_f >= N_f,min) plus two geometric checks the
paper does not have (both configurable, see PlaneConfig and docs/planes.md):

- ill-conditioning: s2 / s3 >= min_singular_ratio. Points from one lane of a straight road lie
  near a line; the plane's rotation about that line (the cross-slope) is then set by noise. The
  fit is reported as 'ill-conditioned' instead of returning a random tilt. Several lanes fix it.
- tilt: the normal within max_tilt_deg of local up, so a vertical 'plane' (one lane over a crest:
  the points lie in the vertical plane of the road, with tiny residuals) is not taken for a road.

With `fault_exclusion=False` (the paper's 'no FE' ablation) none of these run: the plane of all
points is AVAILABLE whenever it is geometrically defined (>= 3 points, not collinear).

`RoadPlane.sigma_m` is the RMS of the used points' distances to their plane, floored at
min_sigma_m: the paper sets Sigma_PC "by the size of residual in plane fitting" (Sec. 4.5). The
factor's sigma adds the plane's own uncertainty: `offset_sigma_m` below, or the full covariance
at the vehicle (`plane.uncertainty`, chosen by `PlaneConfig.sigma_model`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from coplane.geo import up_vector
from coplane.plane.config import PlaneConfig
from coplane.plane.fit import (
    Degenerate,
    PlaneFit,
    antenna_offset,
    constraint_error,
    fit_plane,
    plane_through_three,
    unit_vector,
)
from coplane.typing import Vec


class PlaneStatus(StrEnum):
    """Outcome of plane construction; the values are the wire names (messages.PlaneStatusName)."""

    AVAILABLE = "available"
    AVAILABLE_AFTER_FE = "available-after-fe"
    UNAVAILABLE = "unavailable"


def _frozen(a: ArrayLike, shape: tuple[int, ...] = (3,)) -> Vec:
    out = np.array(a, dtype=float, copy=True).reshape(shape)
    out.flags.writeable = False
    return out


_NAN3 = _frozen([math.nan] * 3)
_NO_POINTS = _frozen(np.empty((0, 3)), (0, 3))


def _json_float(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


@dataclass(frozen=True, eq=False)
class RoadPlane:
    """A vehicle's road plane for one epoch and how it was obtained.

    Plane fields (normal, d_road, d_antenna, centroid, residuals, sigma) describe the last plane
    fitted, also when it was rejected (for plots); they are NaN only when no plane could be fitted
    (degenerate input). Use the plane as a constraint only when `available`.
    """

    status: PlaneStatus
    reason: str | None
    normal: Vec  # unit, upward, ECEF
    d_road: float  # n . p + d_road = 0 on the road surface (eq. 11)
    d_antenna: float  # n . p + d_antenna = 0 at antenna height (eqs. 12-13): d_road - h
    centroid: Vec  # of the used points, on the road surface
    antenna_height_m: float
    n_points_initial: int  # N_f before fault exclusion
    n_points_used: int  # N_f after it (points of the final fit)
    residual_max_m: float  # eq. (14) over the used points
    residual_rms_m: float
    sigma_m: float  # the plane factor's sigma: max(residual_rms_m, min_sigma_m)
    excluded: int  # points removed by fault exclusion
    points_used: Vec  # (n_points_used, 3) road points of the final fit
    points_excluded: Vec  # (excluded, 3)
    tilt_deg: float  # normal vs local up
    conditioning: float  # s2 / s3 of the final fit (inf on an exact plane)
    used_index: NDArray[np.intp] = field(default_factory=lambda: np.empty(0, dtype=np.intp))
    """Rows of the input points that are `points_used` (to match per-point records after FE)."""

    @property
    def available(self) -> bool:
        return self.status is not PlaneStatus.UNAVAILABLE

    @property
    def u_pc(self) -> Vec:
        """Eq. (23)'s unit vector ``u_PC = -n``."""
        return -self.normal

    @property
    def p_d_prime(self) -> float:
        """Eq. (22)'s ``P'^D``: the antenna plane's offset."""
        return self.d_antenna

    def constraint_error(self, p: ArrayLike) -> float:
        """Eq. (24) at antenna position `p`: signed height above the antenna plane (m)."""
        if not math.isfinite(self.d_antenna):
            raise ValueError(f"no plane was fitted ({self.reason})")
        return constraint_error(self.normal, self.d_antenna, p)

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly form (plain floats and lists; NaN and inf become None)."""
        return {
            "status": self.status.value,
            "reason": self.reason,
            "normal": [_json_float(x) for x in self.normal] if math.isfinite(self.d_road) else None,
            "d_road_m": _json_float(self.d_road),
            "d_antenna_m": _json_float(self.d_antenna),
            "centroid_ecef_m": [_json_float(x) for x in self.centroid]
            if math.isfinite(self.d_road)
            else None,
            "antenna_height_m": float(self.antenna_height_m),
            "n_points_initial": int(self.n_points_initial),
            "n_points_used": int(self.n_points_used),
            "residual_max_m": _json_float(self.residual_max_m),
            "residual_rms_m": _json_float(self.residual_rms_m),
            "sigma_m": _json_float(self.sigma_m),
            "excluded": int(self.excluded),
            "tilt_deg": _json_float(self.tilt_deg),
            "conditioning": _json_float(self.conditioning),
            "points_used": [[float(c) for c in p] for p in self.points_used],
            "points_excluded": [[float(c) for c in p] for p in self.points_excluded],
        }


def detection_failures(fit: PlaneFit, points: Vec, config: PlaneConfig) -> list[str]:
    """Why a fitted plane is not available (empty list: it is). Eq. (16) plus the geometric rules."""
    reasons: list[str] = []
    n = points.shape[0]
    if n < config.n_min:
        reasons.append(f"too-few-points: {n} < {config.n_min}")
    if fit.conditioning < config.min_singular_ratio:
        reasons.append(
            f"ill-conditioned: s2/s3 = {fit.conditioning:.2f} < {config.min_singular_ratio:g} "
            "(points near one line, cross-slope undetermined)"
        )
    if config.max_tilt_deg is not None and fit.tilt_deg > config.max_tilt_deg:
        reasons.append(f"tilt {fit.tilt_deg:.1f} deg > {config.max_tilt_deg:g} deg from local up")
    res_max = float(fit.distances(points).max())
    if res_max > config.t_f_m:  # eq. (16): Res_max <= T_f passes
        reasons.append(f"residual {res_max:.2f} m > T_f {config.t_f_m:g} m")
    return reasons


RANSAC_DRAWS_PER_ITERATION = 3
"""Bound on random triples drawn per RANSAC iteration (see `ransac_inliers`)."""


def ransac_inliers(
    points: Vec,
    config: PlaneConfig,
    rng: np.random.Generator,
    up: ArrayLike | None = None,
) -> NDArray[np.bool_] | None:
    """Algorithm 1: the largest set of points closer than T_f to a plane through 3 random points.

    I_max counts plane hypotheses. A triple that gives no valid hypothesis is skipped and redrawn
    (at most RANSAC_DRAWS_PER_ITERATION * I_max draws in all, so the cost stays bounded): a
    collinear triple (no plane), or, when max_tilt_deg is set, a plane tilted beyond it from `up`
    (default: local up at the centroid). The second rule is needed with the paper's T_f = 5 m:
    on a road narrower than 2 T_f, the steep plane through three points of one lane has every
    point, outliers included, within T_f; Algorithm 1 would stop at once with all points as
    'inliers' and fault exclusion would never exclude anything.

    Stops early once every point is an inlier; ties keep the first set found (the '>' of line
    12). Returns the inlier mask, or None when no valid hypothesis was drawn.
    """
    n = points.shape[0]
    if n < 3:
        return None
    cos_max = None
    if config.max_tilt_deg is not None:
        u = unit_vector(up_vector(points.mean(axis=0)) if up is None else np.asarray(up, dtype=float))
        cos_max = math.cos(math.radians(config.max_tilt_deg))
    best: NDArray[np.bool_] | None = None
    best_n = 0
    iterations = 0
    for _ in range(RANSAC_DRAWS_PER_ITERATION * config.ransac_iterations):
        tri = rng.choice(n, size=3, replace=False)
        plane = plane_through_three(points[tri])
        if plane is None:
            continue
        normal, _ = plane
        if cos_max is not None and abs(float(normal @ u)) < cos_max:
            continue
        iterations += 1
        dist = np.abs((points - points[tri[0]]) @ normal)  # eq. (15), free of ECEF cancellation
        inliers = dist < config.t_f_m  # line 7: strict
        n_in = int(np.count_nonzero(inliers))
        if n_in > best_n:
            best, best_n = inliers, n_in
        if best_n == n or iterations == config.ransac_iterations:
            break
    return best


def _plane(
    status: PlaneStatus,
    reason: str | None,
    fit: PlaneFit | Degenerate | None,
    used: Vec,
    excluded: Vec,
    n_initial: int,
    antenna_height_m: float,
    config: PlaneConfig,
    used_index: NDArray[np.intp],
) -> RoadPlane:
    used_index = np.array(used_index, dtype=np.intp, copy=True)
    used_index.flags.writeable = False
    if isinstance(fit, PlaneFit):
        res = fit.distances(used)
        rms = float(np.sqrt(np.mean(res**2)))
        return RoadPlane(
            status=status,
            reason=reason,
            normal=fit.normal,
            d_road=fit.d,
            d_antenna=antenna_offset(fit.d, antenna_height_m),
            centroid=fit.centroid,
            antenna_height_m=antenna_height_m,
            n_points_initial=n_initial,
            n_points_used=used.shape[0],
            residual_max_m=float(res.max()),
            residual_rms_m=rms,
            sigma_m=max(rms, config.min_sigma_m),
            excluded=excluded.shape[0],
            points_used=_frozen(used, used.shape),
            points_excluded=_frozen(excluded, excluded.shape),
            tilt_deg=fit.tilt_deg,
            conditioning=fit.conditioning,
            used_index=used_index,
        )
    return RoadPlane(
        status=PlaneStatus.UNAVAILABLE,
        reason=reason,
        normal=_NAN3,
        d_road=math.nan,
        d_antenna=math.nan,
        centroid=_NAN3,
        antenna_height_m=antenna_height_m,
        n_points_initial=n_initial,
        n_points_used=used.shape[0],
        residual_max_m=math.nan,
        residual_rms_m=math.nan,
        sigma_m=math.nan,
        excluded=excluded.shape[0],
        points_used=_frozen(used, used.shape),
        points_excluded=_frozen(excluded, excluded.shape),
        tilt_deg=math.nan,
        conditioning=math.nan,
        used_index=used_index,
    )


def construct_plane(
    points_road: ArrayLike,
    antenna_height_m: float,
    config: PlaneConfig,
    rng: np.random.Generator,
    up: ArrayLike | None = None,
) -> RoadPlane:
    """Paper Fig. 3 for one vehicle and epoch: fit, detect, fault exclusion, re-fit, re-detect.

    `points_road` (N, 3) are road-projected fitting points (`PositionHistory.select`), ECEF.
    `up` overrides the local up that orients the normal (only for points in a local frame).
    """
    pts = np.asarray(points_road, dtype=float).reshape(-1, 3)
    if not np.isfinite(pts).all():
        raise ValueError("fitting points contain NaN or infinite coordinates")
    if not (math.isfinite(antenna_height_m) and antenna_height_m >= 0.0):
        raise ValueError(f"antenna height must be finite and >= 0, got {antenna_height_m!r}")
    n0 = pts.shape[0]
    none = _NO_POINTS
    every = np.arange(n0, dtype=np.intp)

    def out(
        status: PlaneStatus,
        reason: str | None,
        fit: PlaneFit | Degenerate | None,
        used: Vec,
        excl: Vec,
        used_index: NDArray[np.intp] = every,
    ) -> RoadPlane:
        return _plane(status, reason, fit, used, excl, n0, antenna_height_m, config, used_index)

    if n0 == 0:
        return out(PlaneStatus.UNAVAILABLE, "no fitting points", None, none, none)
    up_vec = up_vector(pts.mean(axis=0)) if up is None else np.asarray(up, dtype=float)
    fit0 = fit_plane(pts, up_vec)
    if isinstance(fit0, Degenerate):
        return out(PlaneStatus.UNAVAILABLE, fit0.reason, fit0, pts, none)
    if not config.fault_exclusion:  # paper's 'no FE' ablation: no detection, no exclusion
        return out(PlaneStatus.AVAILABLE, None, fit0, pts, none)
    if n0 < config.n_min:  # exclusion only removes points: it cannot help
        return out(PlaneStatus.UNAVAILABLE, f"too-few-points: {n0} < {config.n_min}", fit0, pts, none)
    failures = detection_failures(fit0, pts, config)
    if not failures:
        return out(PlaneStatus.AVAILABLE, None, fit0, pts, none)

    inliers = ransac_inliers(pts, config, rng, up_vec)
    if inliers is None:
        reason = f"{'; '.join(failures)}; fault exclusion found no valid triple"
        return out(PlaneStatus.UNAVAILABLE, reason, fit0, pts, none)
    used, excl = pts[inliers], pts[~inliers]
    if used.shape[0] < config.n_min:
        reason = f"too-few-points: {used.shape[0]} < {config.n_min} after FE ({'; '.join(failures)} before)"
        return out(PlaneStatus.UNAVAILABLE, reason, fit0, pts, none)
    kept = np.flatnonzero(inliers)
    fit1 = fit_plane(used, up_vec)
    if isinstance(fit1, Degenerate):
        return out(PlaneStatus.UNAVAILABLE, f"{fit1.reason} after FE", fit1, used, excl, kept)
    failures = detection_failures(fit1, used, config)
    if failures:
        return out(PlaneStatus.UNAVAILABLE, f"{'; '.join(failures)} after FE", fit1, used, excl, kept)
    note = f"fault exclusion removed {excl.shape[0]} of {n0} points" if excl.shape[0] else None
    return out(PlaneStatus.AVAILABLE_AFTER_FE, note, fit1, used, excl, kept)


def offset_sigma_m(sigmas_up_m: ArrayLike, vehicle_ids: Sequence[str]) -> float:
    """Uncertainty of a plane's offset from the uncertainty of the positions it was fitted to.

    The fit residual (RoadPlane.sigma_m) only measures how well the points agree with each other;
    if all of them sit 1 m too high, the plane does too and says nothing. The offset inherits the
    points' vertical errors, averaged over what is independent: a vehicle's consecutive solved
    positions share most of their error (multipath and NLOS are correlated over seconds), so the
    averaging counts distinct vehicles, not points:  sigma_off^2 = mean(sigma_up_i^2) / n_vehicles.
    Points with unknown sigma (NaN) are ignored; with none known the result is 0.
    """
    s = np.asarray(sigmas_up_m, dtype=float)
    ok = np.isfinite(s)
    if not ok.any():
        return 0.0
    n_veh = max(1, len({v for v, k in zip(vehicle_ids, ok, strict=True) if k}))
    return float(math.sqrt(float(np.mean(s[ok] ** 2)) / n_veh))
