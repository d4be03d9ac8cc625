"""Which rows one RAIM exclusion takes (`coplane.gnss.lsq.worst_rows`): the worst, and every row
whose w-test is the same test, so that rounding never picks between them."""

from __future__ import annotations

import numpy as np

from coplane.gnss.lsq import weighted_solve, worst_rows


def _design(n_a: int, n_b: int, rng: np.random.Generator) -> np.ndarray:
    """Unit line-of-sight rows over the sky, a clock column per system (n_b = 0: one system)."""
    az = rng.uniform(0.0, 2 * np.pi, n_a + n_b)
    el = rng.uniform(0.3, 1.4, n_a + n_b)
    los = np.stack([np.cos(el) * np.sin(az), np.cos(el) * np.cos(az), np.sin(el)], axis=1)
    clocks = np.zeros((n_a + n_b, 2 if n_b else 1))
    clocks[:n_a, 0] = 1.0
    if n_b:
        clocks[n_a:, 1] = 1.0
    return np.hstack([-los, clocks])


def _residuals(a: np.ndarray, y: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    return y - a @ weighted_solve(a, y, 1.0 / sigma)


def _faulted(a: np.ndarray, row: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Unit-sigma noise, with 40 sigma on `row`: the post-fit residuals and the sigmas."""
    sigma = np.full(len(a), 1.0)
    y = rng.normal(0.0, 1.0, len(a))
    y[row] += 40.0
    return _residuals(a, y, sigma), sigma


def test_one_fault_among_many_takes_one_row() -> None:
    rng = np.random.default_rng(1)
    a = _design(10, 0, rng)
    assert worst_rows(a, *_faulted(a, 3, rng)).tolist() == [3]


def test_a_fault_in_a_two_satellite_system_takes_both_in_any_order() -> None:
    """Their clock takes the pair's mean: their residuals are proportional, their |w| equal."""
    rng = np.random.default_rng(2)
    a = _design(6, 2, rng)
    sigma = np.array([1.0, 1.2, 0.8, 1.0, 1.5, 1.1, 0.9, 1.3])
    y = rng.normal(0.0, 1.0, 8)
    y[7] += 40.0
    for order in (np.arange(8), np.arange(8)[::-1], rng.permutation(8)):
        rows = worst_rows(a[order], _residuals(a[order], y[order], sigma[order]), sigma[order])
        assert sorted(order[rows].tolist()) == [6, 7]


def test_with_one_redundant_row_every_row_is_the_same_test() -> None:
    """Five satellites, four unknowns: a fault can be detected, never located."""
    rng = np.random.default_rng(3)
    a = _design(5, 0, rng)
    v, sigma = _faulted(a, 0, rng)
    assert worst_rows(a, v, sigma).tolist() == [0, 1, 2, 3, 4]
    # rows past `rows` (a Doppler solve's pseudo rows) are never taken
    assert worst_rows(a, v, sigma, rows=3).tolist() == [0, 1, 2]


def test_chi2_threshold_is_scipy_stats_quantile() -> None:
    """The global test's threshold comes from scipy.special (scipy.stats is not imported for it):
    it must be scipy.stats.chi2's quantile to the bit, so that no RAIM decision moves."""
    from scipy.stats import chi2

    from coplane.gnss.lsq import chi2_threshold

    for p in (1e-7, 1e-5, 1e-3, 0.01, 0.05, 0.1, 0.5):
        for dof in range(1, 60):
            assert chi2_threshold(p, dof) == float(chi2.ppf(1.0 - p, dof)), (p, dof)
    assert chi2_threshold(0.01, 0) == float("inf")
