"""Least-squares helpers shared by SPP and Doppler velocity: the weighted solve and the
integrity tests (global chi-square test + w-test)."""

from __future__ import annotations

import functools
import math

import numpy as np
from scipy.stats import chi2

from coplane.typing import AnyArray, Vec


@functools.lru_cache(maxsize=1024)
def chi2_threshold(false_alarm_probability: float, dof: int) -> float:
    """Upper chi-square quantile for the global residual test; inf when there is no redundancy."""
    return float(chi2.ppf(1.0 - false_alarm_probability, dof)) if dof > 0 else math.inf


def weighted_solve(a: Vec, v: Vec, w: Vec) -> AnyArray:
    """Least-squares solution of the rows `a` x = `v` weighted by `w` (1/sigma). The normal
    equations are well conditioned for SPP's and Doppler's 4-6 unknowns of unit line-of-sight
    rows, and several times cheaper than lstsq's SVD, which stays the fallback when singular."""
    aw = a * w[:, None]
    try:
        return np.linalg.solve(aw.T @ aw, aw.T @ (v * w))
    except np.linalg.LinAlgError:
        return np.linalg.lstsq(aw, v * w, rcond=None)[0]


def w_tests(a: Vec, v: Vec, sigma: Vec) -> Vec:
    """Baarda's standardised residuals v_i / sqrt(Qv_ii), Qv = Sigma - A (A' W A)^-1 A'.

    A measurement that alone determines an unknown (e.g. the only satellite of a constellation,
    which fixes that constellation's clock) has Qv_ii = 0 and gets w = 0: it cannot be tested.
    """
    w = 1.0 / sigma**2
    n = np.linalg.inv(a.T @ (a * w[:, None]))
    qv = sigma**2 - np.einsum("ij,jk,ik->i", a, n, a)
    out = np.zeros_like(v)
    ok = qv > 1e-9 * sigma**2
    out[ok] = v[ok] / np.sqrt(qv[ok])
    return out
