"""Least-squares helpers shared by SPP, Doppler velocity and the graph's FDE: the weighted solve
and the integrity tests (global chi-square test, w-test, which rows one exclusion takes)."""

from __future__ import annotations

import functools
import math

import numpy as np
from scipy.special import gammaincinv

from coplane.typing import AnyArray, Vec


@functools.lru_cache(maxsize=1024)
def chi2_threshold(false_alarm_probability: float, dof: int) -> float:
    """Upper chi-square quantile for the global residual test; inf when there is no redundancy.

    `scipy.stats.chi2.ppf(1 - p, dof)` is 2 P^-1(dof / 2, 1 - p), P the regularised lower
    incomplete gamma function: taken from scipy.special, the same function scipy.stats calls
    (the same value to the bit, tests/gnss/test_lsq.py), because importing scipy.stats took half
    of a fusion server's import time and most of its modules."""
    return float(2 * gammaincinv(dof / 2, 1.0 - false_alarm_probability)) if dof > 0 else math.inf


def weighted_solve(a: Vec, v: Vec, w: Vec) -> AnyArray:
    """Least-squares solution of the rows `a` x = `v` weighted by `w` (1/sigma). The normal
    equations are well conditioned for SPP's and Doppler's 4-6 unknowns of unit line-of-sight
    rows, and several times cheaper than lstsq's SVD, which stays the fallback when singular."""
    aw = a * w[:, None]
    try:
        return np.linalg.solve(aw.T @ aw, aw.T @ (v * w))
    except np.linalg.LinAlgError:
        return np.linalg.lstsq(aw, v * w, rcond=None)[0]


# |correlation| of two rows' w-tests above 1 - this: they are the same test. Rounding leaves
# ~1e-12 on an exact 1; geometry alone does not come this close.
INSEPARABLE_TOL = 1e-6


def w_tests(a: Vec, v: Vec, sigma: Vec) -> tuple[Vec, AnyArray, Vec, np.ndarray]:
    """Baarda's standardised residuals v_i / sqrt(Qv_ii), Qv = Sigma - A (A' W A)^-1 A', with
    (A' W A)^-1, the diagonal of Qv and the rows that can be tested.

    A measurement that alone determines an unknown (e.g. the only satellite of a constellation,
    which fixes that constellation's clock) has Qv_ii = 0 and gets w = 0: it cannot be tested.
    """
    w = 1.0 / sigma**2
    n = np.linalg.inv(a.T @ (a * w[:, None]))
    qv = sigma**2 - np.einsum("ij,jk,ik->i", a, n, a)
    out = np.zeros_like(v)
    ok = qv > 1e-9 * sigma**2
    out[ok] = v[ok] / np.sqrt(qv[ok])
    return out, n, qv, ok


def worst_rows(a: Vec, v: Vec, sigma: Vec, rows: int | None = None) -> np.ndarray:
    """The row with the largest |w| among the first `rows` (all: None), with every row among them
    whose w-test is the same test (`inseparable`): the rows to exclude together. With one
    redundant measurement every row is the same test, so the fault cannot be located at all."""
    w, n, qv, ok = w_tests(a, v, sigma)
    rows = len(v) if rows is None else rows
    worst = int(np.argmax(np.abs(w[:rows])))
    group = inseparable(a, sigma**2, n, qv, ok, worst)
    return group[group < rows]


def inseparable(a: Vec, var: Vec, q_x: AnyArray, q_v: Vec, ok: np.ndarray, worst: int) -> np.ndarray:
    """The rows whose w-test is perfectly correlated with row `worst`'s (worst included), for the
    least-squares rows `a` with variances `var`, unknowns' covariance `q_x` and post-fit residual
    variances `q_v` (testable where `ok`). The data cannot tell which of them holds the fault, so
    they are excluded together. A system with two satellites and a clock of its own is the common
    case: its clock takes their mean, their post-fit residuals are proportional and their |w|
    equal, so picking the larger lets rounding choose; a Doppler read back as float32 (UBX) moved
    a track 0.1 m that way (docs/fgo.md, "Fault detection and exclusion")."""
    row = -(a[worst] @ q_x @ a.T)
    row[worst] += var[worst]
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = np.abs(row) / np.sqrt(q_v[worst] * q_v)
    group = np.flatnonzero(ok & (corr > 1.0 - INSEPARABLE_TOL))
    return group if worst in group else np.union1d(group, [worst])
