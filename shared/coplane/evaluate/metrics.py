"""Accuracy statistics: errors in the local ENU frame at the truth point, no trajectory alignment.

Availability (share of truth epochs that have a solution) is always reported beside the errors:
an estimator that drops hard epochs must not look better for it.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass

import numpy as np

from coplane.geo import ecef_to_geodetic, enu_rotation
from coplane.gtime import GpsTime
from coplane.typing import Vec


@dataclass(frozen=True)
class AccuracyStats:
    n_truth: int
    n_solved: int
    availability: float
    h_rmse_m: float
    v_rmse_m: float
    cep95_m: float
    h_max_m: float
    v_max_m: float
    h_mean_m: float
    v_bias_m: float  # mean signed vertical error

    def as_dict(self) -> dict[str, float | int]:
        return asdict(self)


def enu_errors(solutions: Mapping[GpsTime, Vec], truth: Mapping[GpsTime, Vec]) -> tuple[list[GpsTime], Vec]:
    """(times, N x 3 ENU errors) for every truth epoch that has a solution, in time order."""
    times = sorted(t for t in truth if t in solutions)
    errs = np.zeros((len(times), 3))
    for k, t in enumerate(times):
        ref = np.asarray(truth[t], dtype=float)
        lat, lon, _ = ecef_to_geodetic(ref)
        errs[k] = enu_rotation(lat, lon) @ (np.asarray(solutions[t], dtype=float) - ref)
    return times, errs


CHI2_95_2DOF = 5.991  # chi-square 95 % quantile, 2 degrees of freedom


@dataclass(frozen=True)
class EpochCheck:
    """One epoch's error against its reported covariance."""

    h_in95: bool  # horizontal error inside the 95 % ellipse
    v_in95: bool  # vertical error within 1.96 sigma
    nees: float  # normalised estimation error squared, 3-D (chi-square with 3 dof if honest)


@dataclass(frozen=True)
class Consistency:
    """Whether the reported covariances describe the errors: shares inside the 95 % regions (0.95
    if honest) and the mean NEES (3 if honest; below it the covariance is too cautious, above it
    over-confident, which the shares alone do not tell once every epoch is inside)."""

    n: int
    h_in95: float
    v_in95: float
    nees: float

    @classmethod
    def of(cls, checks: Sequence[EpochCheck]) -> Consistency:
        if not checks:
            return cls(0, math.nan, math.nan, math.nan)
        n = len(checks)
        return cls(
            n,
            sum(c.h_in95 for c in checks) / n,
            sum(c.v_in95 for c in checks) / n,
            float(np.mean([c.nees for c in checks])),
        )


def covariance_checks(
    times: Sequence[GpsTime],
    errors: Vec,
    covariances: Mapping[GpsTime, Vec],
    truth: Mapping[GpsTime, Vec],
) -> list[EpochCheck]:
    """One check per epoch with a finite reported ECEF covariance (the others are left out).
    `times`, `errors`: as `enu_errors`. A singular covariance claims no error at all in some
    direction: its epoch is outside both regions with an infinite NEES, never an exception."""
    out: list[EpochCheck] = []
    for t, e in zip(times, errors, strict=True):
        cov = covariances.get(t)
        if cov is None or not np.all(np.isfinite(cov)):
            continue
        r = enu_rotation(*ecef_to_geodetic(np.asarray(truth[t], dtype=float))[:2])
        c = r @ np.asarray(cov, dtype=float).reshape(3, 3) @ r.T
        try:
            h2 = float(e[:2] @ np.linalg.solve(c[:2, :2], e[:2]))
            nees = float(e @ np.linalg.solve(c, e))
        except np.linalg.LinAlgError:
            out.append(EpochCheck(False, False, math.inf))
            continue
        v_var = float(c[2, 2])
        out.append(
            EpochCheck(
                0.0 <= h2 <= CHI2_95_2DOF, v_var > 0.0 and abs(float(e[2])) <= 1.96 * math.sqrt(v_var), nees
            )
        )
    return out


def accuracy(solutions: Mapping[GpsTime, Vec], truth: Mapping[GpsTime, Vec]) -> AccuracyStats:
    _, e = enu_errors(solutions, truth)
    n_truth = len(truth)
    if len(e) == 0:
        nan = math.nan
        return AccuracyStats(n_truth, 0, 0.0, nan, nan, nan, nan, nan, nan, nan)
    p = pooled_stats(e)
    h, v = _horizontal_vertical(e)
    return AccuracyStats(
        n_truth=n_truth,
        n_solved=p.n,
        availability=p.n / n_truth if n_truth else 0.0,
        h_rmse_m=p.h_rmse_m,
        v_rmse_m=p.v_rmse_m,
        cep95_m=float(np.percentile(h, 95)),
        h_max_m=p.h_max_m,
        v_max_m=p.v_max_m,
        h_mean_m=float(h.mean()),
        v_bias_m=float(v.mean()),
    )


@dataclass(frozen=True)
class PooledStats:
    """Errors pooled over vehicles (and epochs) of one group, e.g. one environment: the tail too."""

    n: int
    h_rmse_m: float
    v_rmse_m: float
    h_p50_m: float
    h_p99_m: float
    h_max_m: float
    v_max_m: float
    # signed mean vertical error: a bias (a screening rule that cuts one tail of the noise makes
    # one; a road map built from biased heights inherits it) that RMSE does not separate
    v_mean_m: float = math.nan

    def as_dict(self) -> dict[str, float | int]:
        return asdict(self)


def _horizontal_vertical(errors: Vec) -> tuple[Vec, Vec]:
    """Horizontal error sqrt(E^2 + N^2) and signed vertical error of N x 3 ENU errors."""
    return np.hypot(errors[:, 0], errors[:, 1]), errors[:, 2]


ENVIRONMENT_ORDER = ("open", "medium", "deep", "underpass")  # the simulator's sections, open first


def pooled_stats(errors: Vec) -> PooledStats:
    """Statistics of N x 3 ENU errors (NaN when N is 0)."""
    if len(errors) == 0:
        nan = math.nan
        return PooledStats(0, nan, nan, nan, nan, nan, nan, nan)
    h, v = _horizontal_vertical(errors)
    return PooledStats(
        n=len(errors),
        h_rmse_m=float(np.sqrt(np.mean(h**2))),
        v_rmse_m=float(np.sqrt(np.mean(v**2))),
        h_p50_m=float(np.median(h)),
        h_p99_m=float(np.percentile(h, 99)),
        h_max_m=float(h.max()),
        v_max_m=float(np.abs(v).max()),
        v_mean_m=float(np.mean(v)),
    )


def fleet_errors(
    positions: Mapping[str, Mapping[GpsTime, Vec]],
    truth: Mapping[str, Mapping[GpsTime, Vec]],
    keep: Callable[[str, GpsTime], bool] | None = None,
) -> Vec:
    """N x 3 ENU errors of every vehicle's solved epochs pooled (only those `keep(vehicle, t)`
    accepts): the fleet's accuracy as one number, or on a subset such as the epochs on mapped
    roads."""
    rows: list[Vec] = []
    for vid, by_t in truth.items():
        times, e = enu_errors(positions.get(vid, {}), by_t)
        rows += [row for t, row in zip(times, e, strict=True) if keep is None or keep(vid, t)]
    return np.array(rows).reshape(-1, 3)


def accuracy_by_environment(
    solutions: Mapping[str, Mapping[GpsTime, Vec]],
    truth: Mapping[str, Mapping[GpsTime, Vec]],
    environment: Mapping[str, Mapping[GpsTime, str]],
) -> dict[str, PooledStats]:
    """Pooled over vehicles: "all", then each environment label of the truth (open first).

    Where the deep canyons and the underpass are is where methods differ; a fleet RMSE alone hides
    whether it comes from there or from everywhere.
    """
    errs: list[Vec] = []
    labels: list[str] = []
    for vid in sorted(truth):
        times, e = enu_errors(solutions.get(vid, {}), truth[vid])
        env = environment.get(vid, {})
        errs.append(e)
        labels += [env.get(t, "") for t in times]
    allerr = np.concatenate(errs) if errs else np.zeros((0, 3))
    lab = np.array(labels, dtype=object)
    out = {"all": pooled_stats(allerr)}
    present = {x for x in labels if x}
    for name in [*[k for k in ENVIRONMENT_ORDER if k in present], *sorted(present - set(ENVIRONMENT_ORDER))]:
        out[name] = pooled_stats(allerr[lab == name])
    return out
