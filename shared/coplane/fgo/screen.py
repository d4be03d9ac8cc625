"""Fault detection and exclusion of a vehicle epoch's pseudoranges before they enter the graph.

The paper removes NLOS / multipath faults before its factor graph by cooperative integrity
monitoring (its ref. [28]); a robust kernel alone does not (docs/fgo.md, "Fault detection and
exclusion"). This is the estimator's own FDE: a prior-aided RAIM on the linearised single-epoch
problem around the predicted position (last estimate + Doppler / motion displacement):

    unknowns  x = (dp, one clock per system);   prior  dp ~ N(0, P_pred)
    residual  r_i = rho_i + c dt_s,i - |s_i - p_pred|  ~  -u_i . dp + b_sys(i) + e_i,  e_i ~ N(0, s_i^2)

Weighted least squares gives the post-fit residuals v and their covariance Q_v = R - H Q_x H^T;
the satellite with the largest standardised residual |w_i| = |v_i| / sqrt(Q_v,ii) above `k` is
excluded and the test repeated (Baarda's w-test, iterated), while at least `min_keep`
pseudoranges remain. The prior makes faults detectable even with 4-5 satellites, where
snapshot RAIM has no redundancy: that is what the EKF baselines' innovation gate does, done here
jointly over the epoch instead of one satellite at a time. If most of a well-observed epoch
fails, the prediction is what is wrong (a long outage, a diverged state): nothing is excluded.

Written with numpy because GTSAM has no snapshot RAIM: the graph's own robust machinery
(M-estimators, GNC) works on the whole window and was measured weaker for this (docs/fgo.md).
"""

from __future__ import annotations

import dataclasses
import statistics
from dataclasses import dataclass

import numpy as np

from coplane.estimation.validate import ValidPseudoranges
from coplane.gnss.constants import C
from coplane.gnss.lsq import inseparable
from coplane.numeric import row_norms
from coplane.typing import Mat, Vec


@dataclass(frozen=True)
class ScreenResult:
    """Which rows survive, and the standardised residuals of the excluded ones (for diagnostics)."""

    keep: np.ndarray  # boolean mask over the input rows
    excluded_w: tuple[float, ...]
    prediction_rejected: bool  # most of the epoch failed: the prediction, not the data, is wrong
    # a-posteriori variance factor of the kept pseudoranges (sum of squared standardised post-fit
    # residuals over the redundancy), 1.0 when it cannot be estimated
    variance_factor: float = 1.0
    # signed standardised post-fit residual v / sqrt(Q_v) of each input row once the test passed
    # (positive: measured longer than the fit, as NLOS makes it); NaN where excluded or not
    # testable; None when the test did not run to a pass. The cooperative check adds them up.
    w_signed: np.ndarray | None = None
    # the fitted position minus the predicted one (m, ECEF) and its covariance, once the test
    # passed: for a rejected prediction, where the epoch on its own puts the vehicle
    offset_m: np.ndarray | None = None
    offset_cov: np.ndarray | None = None


def design_matrix(prs: ValidPseudoranges, position: Vec) -> tuple[Mat, Vec, np.ndarray, list[str]]:
    """The rows' single-epoch linearisation at `position`: H = [-u_i, e_system(i)] (unknowns: the
    position, then one clock per system, systems sorted), the ranges |s_i - p|, each row's system
    index and the systems. The FDE's test and the common errors' covariance
    (`common_error`) share it."""
    los = prs.sat_pos - position
    dist = row_norms(los)
    u = los / dist[:, None]
    systems = sorted(set(prs.systems))
    column = {s: j for j, s in enumerate(systems)}
    sys_idx = np.array([column[s] for s in prs.systems], dtype=int)
    h = np.zeros((len(prs), 3 + len(systems)))
    h[:, :3] = -u
    h[np.arange(len(prs)), 3 + sys_idx] = 1.0
    return h, dist, sys_idx, systems


def screen_pseudoranges(
    prs: ValidPseudoranges,
    predicted: Vec,
    p_pred: Mat,
    k: float,
    *,
    min_keep: int = 4,
    divergence_fraction: float = 0.5,
    divergence_min: int = 6,
    snapshot_fallback: bool = False,
    k_long: float | None = None,
    long_rows: np.ndarray | None = None,
    two_sided: bool = False,
    count_exclusions: bool = False,
    clock_prior: dict[str, tuple[float, float]] | None = None,
    clock_jump_m: float = float("inf"),
) -> ScreenResult:
    """Iterated w-test exclusion of the pseudoranges against the predicted position and its covariance.

    `k_long`: the threshold for a residual measured longer than the fit (v > 0), the only side
    NLOS produces; None: `k` on both sides. GTSAM's asymmetric kernels cannot do this in the
    graph: its robust noise model hands them the Mahalanobis distance, which has no sign
    (docs/fgo.md), so the asymmetry lives here. `long_rows`: the rows `k_long` applies to (a
    boolean mask, e.g. the low or weak satellites: `weak_rows`); None: every row. `two_sided`:
    `k_long` tests both signs of those rows, which keeps the test unbiased for symmetric noise
    (cutting only the long tail of clean residuals shifts the fit).

    `snapshot_fallback`: when the prediction is rejected, test the epoch again without the prior
    (snapshot RAIM: the epoch's own redundancy) instead of keeping every pseudorange; an over-
    confident prediction in a canyon must not let the NLOS ranges it failed to explain through.

    `clock_prior`: system -> (predicted receiver clock, its sigma), metres: the clock is held to
    it instead of free (`FgoConfig.fde_clock_prior`); beyond `clock_jump_m` (and 5 sigma) from the
    system's median residual it is ignored. Snapshot RAIM never uses it.

    `count_exclusions`: the prediction is also rejected when the iterated test, one exclusion
    after another, has excluded more than `divergence_fraction` of a well-observed epoch. A
    prediction far off but held with a tight covariance passes the first test with most rows:
    the fit absorbs the offset into the position, and each exclusion then leaves the prior
    stronger against the rest, until only the few rows that agree with it remain. On a real car
    after 45 s on 3 satellites this kept 4-5 of 17 satellites for 15 epochs, 80-90 m off."""
    n = len(prs)
    keep = np.ones(n, dtype=bool)
    if n == 0:
        return ScreenResult(keep, (), False)
    h_full, dist, sys_idx, systems = design_matrix(prs, predicted)
    n_sys = len(systems)
    resid = prs.rho + C * prs.sat_clock - dist
    var = prs.sigma**2
    # clocks start from the per-system median residual so that the linear model is centred
    # (statistics.median: np.median's value, without its overhead on a dozen numbers), or from
    # their prediction, which then holds them (`clock_prior`), unless the median lies so far from
    # it that the receiver's clock jumped
    prior_info = np.zeros((3 + n_sys, 3 + n_sys))
    prior_info[:3, :3] = np.linalg.inv(p_pred)
    for j in range(n_sys):
        in_sys = sys_idx == j
        centre = statistics.median(resid[in_sys].tolist())
        held = clock_prior.get(systems[j]) if clock_prior else None
        if held is not None and not clock_jumped(centre, held[0], held[1], clock_jump_m):
            centre = held[0]
            prior_info[3 + j, 3 + j] = 1.0 / held[1] ** 2
        resid[in_sys] -= centre
    excluded: list[float] = []
    n_fail_first: int | None = None

    def rejected() -> ScreenResult:
        """The prediction is what is wrong: test the epoch on its own, or keep every row."""
        if snapshot_fallback:
            # no prior, so no prediction to reject: the w-test runs to its end
            snapshot = screen_pseudoranges(
                prs,
                predicted,
                np.eye(3) * 1e12,
                k,
                min_keep=min_keep,
                divergence_min=n + 1,
                k_long=k_long,
                long_rows=long_rows,
                two_sided=two_sided,
            )
            return dataclasses.replace(snapshot, prediction_rejected=True)
        return ScreenResult(np.ones(n, dtype=bool), (), True)

    # the loop runs once per vehicle epoch on a fusion server (twice or more with exclusions):
    # each numpy call costs microseconds on arrays of a few dozen values, so the kept rows' arrays
    # are taken once per pass, and the whole epoch's are used as they are until a row goes
    n_kept = n
    idx = np.arange(n)
    h, var_k, resid_k = h_full, var, resid
    while n_kept > min_keep:
        w_inv = 1.0 / var_k
        info = prior_info + (h.T * w_inv) @ h
        if excluded:
            # a system whose satellites were all excluded has an unobservable clock: regularise it
            # (before the first exclusion every system has a row, so its diagonal is positive)
            free = np.flatnonzero(np.diag(info)[3:] == 0.0) + 3
            info[free, free] = 1.0
        try:
            q_x = np.linalg.inv(info)
        except np.linalg.LinAlgError:
            break
        x = q_x @ (h.T @ (w_inv * resid_k))
        v = resid_k - h @ x
        q_v = var_k - np.einsum("ij,jk,ik->i", h, q_x, h)
        ok = q_v > 1e-6 * var_k  # a system's only satellite has no redundancy: not testable
        w_abs = np.zeros_like(v)
        w_abs[ok] = np.abs(v[ok]) / np.sqrt(q_v[ok])
        # the test statistic: a long residual is tested against k_long, so scale it onto k
        if k_long is None:
            w = w_abs
        else:
            long_side = np.ones(len(v), dtype=bool) if two_sided else v > 0
            if long_rows is not None:
                long_side &= long_rows[idx]
            w = np.where(long_side, w_abs * (k / k_long), w_abs)
        if n_fail_first is None:
            n_fail_first = int(np.count_nonzero(w > k))
            if n >= divergence_min and n_fail_first > divergence_fraction * n:
                return rejected()
        worst = int(w.argmax())
        if w[worst] <= k:
            var_ok = var_k[ok]
            redundancy = float((q_v[ok] / var_ok).sum())
            signed = np.full(n, np.nan)
            signed[idx[ok]] = v[ok] / np.sqrt(q_v[ok])
            if redundancy >= 1.0:
                factor = float((v[ok] ** 2 / var_ok).sum()) / redundancy
                return ScreenResult(keep, tuple(excluded), False, factor, signed, x[:3], q_x[:3, :3])
            return ScreenResult(keep, tuple(excluded), False, 1.0, signed, x[:3], q_x[:3, :3])
        group = inseparable(h, var_k, q_x, q_v, ok, worst)
        if n_kept - len(group) < min_keep:
            break  # as when min_keep rows are left: the fault cannot go without going below
        for j in group:
            keep[idx[j]] = False
            excluded.append(float(w_abs[j]))  # the standardised residual, not the scaled statistic
        n_kept -= len(group)
        if count_exclusions and n >= divergence_min and len(excluded) > divergence_fraction * n:
            return rejected()
        idx = np.flatnonzero(keep)
        h, var_k, resid_k = h_full[idx], var[idx], resid[idx]
    return ScreenResult(keep, tuple(excluded), False)


def clock_jumped(measured_m: float, predicted_m: float, sigma_m: float, jump_m: float) -> bool:
    """Whether a receiver clock lies so far from its prediction (beyond `jump_m` and 5 sigma)
    that it jumped (a receiver steering its clock by 1 ms): the prediction must then be dropped,
    not tested against."""
    return abs(measured_m - predicted_m) > max(jump_m, 5.0 * sigma_m)


def weak_rows(
    prs: ValidPseudoranges,
    below_elevation_deg: float | None = None,
    below_cn0_dbhz: float | None = None,
    below_best_cn0_db: float | None = None,
) -> Vec:
    """The satellites likely to be NLOS: below `below_elevation_deg`, below `below_cn0_dbhz`, or
    more than `below_best_cn0_db` under the epoch's strongest satellite (any that is set; none
    set: every satellite). The relative form follows the receiver: a phone's or a choke ring's
    C/N0 levels differ by many dB from the car-roof patch an absolute threshold would be chosen
    for, while NLOS costs the reflection's loss on any antenna. An unreported elevation or C/N0
    (NaN) does not make a satellite weak: without evidence it keeps the symmetric test."""
    if below_elevation_deg is None and below_cn0_dbhz is None and below_best_cn0_db is None:
        return np.ones(len(prs), dtype=bool)
    weak = np.zeros(len(prs), dtype=bool)
    with np.errstate(invalid="ignore"):  # NaN compares False
        if below_elevation_deg is not None:
            weak |= prs.elevation < np.radians(below_elevation_deg)
        if below_cn0_dbhz is not None:
            weak |= prs.cn0 < below_cn0_dbhz
        if below_best_cn0_db is not None and np.isfinite(prs.cn0).any():
            weak |= prs.cn0 < np.nanmax(prs.cn0) - below_best_cn0_db
    return weak
