"""GAMP cooperative positioning (paper Table I "GAMP", ref. [19]): message passing on the fleet graph.

The fleet's posterior at an epoch factorises into per-vehicle priors and measurement factors:

    p(x | z) ~ prod_v p(x_v | past, Doppler_v) prod_(v,i) p(rho_vi | x_v) prod_(a,b) p(d_ab | x_a, x_b).

Variable nodes are the vehicles' states (the Non-CP EKF state). The input prior N(mu_v, V_v) of
each vehicle is its own prediction: constant velocity from its previous belief, then its Doppler
velocity and clock drift, exactly as the Non-CP EKF (same clock-jump handling and pseudorange gate,
but no pseudorange update). The output channels are the gated pseudoranges (one vehicle each) and
the inter-vehicle ranges (two vehicles), linearised at the current means: y = A x + w. GAMP
(Rangan 2011, sum-product, with vector-valued variable nodes):

    output:  tau_p = sum_j A_ij T_j A_ij',   p = A x - tau_p s,
             s = (y - p) / (sigma^2 + tau_p),  tau_s = 1 / (sigma^2 + tau_p)
    input:   J_j = sum_i A_ij' tau_s A_ij,  T_j = (V_j^-1 + J_j)^-1,
             x_j = T_j (V_j^-1 mu_j + J_j x_j + sum_i A_ij' s_i)

with damping (new = beta * new + (1 - beta) * old on s, tau_s, x, T), iterated to convergence,
then relinearised at the new means. At a fixed point the means solve the linearised joint
least-squares problem exactly ((V^-1 + A' R^-1 A) x = V^-1 mu + A' R^-1 y); the covariances T_j
are GAMP's approximation. The beliefs are written back into the vehicles' filters as the next
epoch's starting point; if GAMP does not converge, each vehicle takes its exact local update.
docs/methods.md has the settings and the approximations.
"""

from __future__ import annotations

import dataclasses
import itertools
import logging
import math
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from coplane.baselines.fleet_filter import EkfConfig
from coplane.baselines.measurements import VehicleMeasurements
from coplane.baselines.non_cp import NonCpEkf
from coplane.baselines.rows import Rows
from coplane.baselines.skeleton import BaselineEstimator, EpochOutcome
from coplane.errors import require_finite_positive
from coplane.estimation.contract import VehicleEstimate
from coplane.estimation.validate import ValidEpoch
from coplane.gnss.constants import C
from coplane.gnss.lsq import chi2_threshold
from coplane.typing import Mat, Vec

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class GampConfig:
    ekf: EkfConfig = field(default_factory=EkfConfig)
    damping: float = 0.5  # beta: weight of the new message (1 = undamped)
    max_iterations: int = 500  # per GAMP run; measured need on the bundled data: <= ~200
    tolerance_m: float = 1e-4  # convergence: no mean component moves more than this (m)
    relinearisations: int = 5
    relinearisation_tolerance_m: float = 1e-3
    range_sigma: float = 0.3  # when a RangeObs has no usable sigma
    range_gate_probability: float = 1e-3
    use_ranging: bool = True
    scalar_nodes: bool = False  # True: textbook scalar GAMP on whitened states (see scalar_gamp)

    def __post_init__(self) -> None:
        if not 0.0 < self.damping <= 1.0:
            raise ValueError(f"damping must be in (0, 1], got {self.damping!r}")
        if self.max_iterations < 1 or self.relinearisations < 1:
            raise ValueError("max_iterations and relinearisations must be >= 1")
        require_finite_positive(self, ("tolerance_m", "relinearisation_tolerance_m", "range_sigma"))


@dataclass
class GampResult:
    means: list[Vec]
    covariances: list[Mat]
    iterations: int
    converged: bool
    last_change: float  # largest mean change of the last iteration


def gamp(
    prior_means: Sequence[Vec],
    prior_covs: Sequence[Mat],
    rows: Sequence[Sequence[tuple[int, Vec]]],
    y: Vec,
    noise_var: Vec,
    damping: float = 0.5,
    max_iterations: int = 100,
    tolerance: float = 1e-4,
) -> GampResult:
    """Damped sum-product GAMP for y = A x + w with Gaussian block priors and Gaussian noise.

    rows[i] lists the (block j, coefficients a_ij) of measurement i; blocks are the variable
    nodes (one vehicle's state), each with a full Gaussian prior N(prior_means[j], prior_covs[j]).

    The blocks are stacked into one state whose beliefs stay block-diagonal (`mask`: each variable
    node keeps its own), so that an iteration is a few matrix products over the whole fleet: with a
    few dozen state components, a dozen small numpy calls per block and iteration cost more than
    the arithmetic.
    """
    sizes = [len(v) for v in prior_means]
    starts = np.concatenate(([0], np.cumsum(sizes))).astype(int)
    n = int(starts[-1])
    m = len(y)
    a = np.zeros((m, n))
    for i, row in enumerate(rows):
        for j, coef in row:
            a[i, starts[j] : starts[j + 1]] += coef
    mask = np.zeros((n, n), dtype=bool)
    vinv = np.zeros((n, n))
    t = np.zeros((n, n))
    for j, c in enumerate(prior_covs):
        blk = slice(starts[j], starts[j + 1])
        mask[blk, blk] = True
        t[blk, blk] = c
        vinv[blk, blk] = np.linalg.inv(np.asarray(c, dtype=float))
    mu = np.concatenate([np.asarray(v, dtype=float).reshape(-1) for v in prior_means]) if n else np.zeros(0)
    vinv_mu = vinv @ mu
    x = mu.copy()
    y = np.asarray(y, dtype=float)
    w = np.asarray(noise_var, dtype=float)
    s = np.zeros(m)
    tau_s: Vec | None = None
    change = math.inf
    it = 0
    for it in range(1, max_iterations + 1):  # `it` is the iteration count returned
        tau_p = np.einsum("ik,ik->i", a @ t, a)  # row i: sum_j a_ij T_j a_ij'
        p = a @ x - tau_p * s
        ts_new = 1.0 / (w + tau_p)
        s_new = (y - p) * ts_new
        s = damping * s_new + (1.0 - damping) * s
        tau_s = ts_new if tau_s is None else damping * ts_new + (1.0 - damping) * tau_s
        jr = np.where(mask, (a.T * tau_s) @ a, 0.0)  # J_j on the diagonal blocks
        tn = np.linalg.inv(vinv + jr)  # block-diagonal: the blocks' own inverses
        tn = np.where(mask, 0.5 * (tn + tn.T), 0.0)
        xn = tn @ (vinv_mu + jr @ x + a.T @ s)
        change = float(np.max(np.abs(xn - x))) if n else 0.0
        x = damping * xn + (1.0 - damping) * x
        t = damping * tn + (1.0 - damping) * t
        if not (math.isfinite(change) and np.all(np.isfinite(x))):
            return _blocks(x, t, starts, it, False, math.inf)
        if change < tolerance:
            return _blocks(x, t, starts, it, True, change)
    return _blocks(x, t, starts, it, False, change)


def _blocks(x: Vec, t: Mat, starts: Vec, it: int, converged: bool, change: float) -> GampResult:
    """The stacked beliefs split back into the variable nodes' means and covariances."""
    spans = [slice(int(a), int(b)) for a, b in itertools.pairwise(starts)]
    return GampResult([x[b].copy() for b in spans], [t[b, b].copy() for b in spans], it, converged, change)


def scalar_gamp(
    prior_means: Sequence[Vec],
    prior_covs: Sequence[Mat],
    rows: Sequence[Sequence[tuple[int, Vec]]],
    y: Vec,
    noise_var: Vec,
    damping: float = 0.5,
    max_iterations: int = 100,
    tolerance: float = 1e-4,
) -> GampResult:
    """Rangan's scalar GAMP on the same problem: each block whitened (x_j = mu_j + L_j u_j,
    u_j ~ N(0, I), L_j L_j' = V_j) and every component of u its own scalar variable node.

    The textbook, fully separable form; kept to show what damping is for (it diverges undamped on
    GNSS-like rows, whose clock column makes A far from zero-mean i.i.d.). Returns x-space beliefs.
    """
    chol = [np.linalg.cholesky(np.asarray(c, dtype=float)) for c in prior_covs]
    mu = [np.asarray(m, dtype=float) for m in prior_means]
    comp = [(j, k) for j in range(len(mu)) for k in range(len(mu[j]))]
    where = {jk: n for n, jk in enumerate(comp)}
    srows = []
    y_w = np.asarray(y, dtype=float).copy()
    for i, row in enumerate(rows):
        out = []
        for j, coef in row:
            y_w[i] -= float(coef @ mu[j])
            c = coef @ chol[j]
            out += [(where[(j, k)], np.array([c[k]])) for k in range(len(c)) if c[k] != 0.0]
        srows.append(out)
    res = gamp(
        [np.zeros(1) for _ in comp],
        [np.eye(1) for _ in comp],
        srows,
        y_w,
        noise_var,
        damping,
        max_iterations,
        tolerance,
    )
    means, covs = [], []
    for j in range(len(mu)):
        idx = [where[(j, k)] for k in range(len(mu[j]))]
        u = np.array([res.means[n][0] for n in idx])
        tu = np.diag([res.covariances[n][0, 0] for n in idx])
        means.append(mu[j] + chol[j] @ u)
        covs.append(chol[j] @ tu @ chol[j].T)
    return GampResult(means, covs, res.iterations, res.converged, res.last_change)


@dataclass
class RangeRow:
    a: str
    b: str
    range_m: float
    sigma_m: float


def cooperative_gamp(
    means: dict[str, Vec],
    covs: dict[str, Mat],
    pos_idx: dict[str, list[int]],
    clock_idx: dict[str, dict[str, int]],
    pseudoranges: dict[str, VehicleMeasurements],
    ranges: Sequence[RangeRow],
    config: GampConfig,
) -> tuple[GampResult, int]:
    """GAMP over the fleet graph with relinearisation: beliefs per vehicle (sorted ids).

    Blocks are the vehicles' full filter states; rows are their pseudoranges (one block each:
    rho_c ~ |p - s| + b_sys) and the ranges (two blocks), linearised at the current means.
    """
    vids = sorted(means)
    block = {v: k for k, v in enumerate(vids)}
    mu = [np.asarray(means[v], dtype=float) for v in vids]
    cv = [np.asarray(covs[v], dtype=float) for v in vids]
    lin = [m.copy() for m in mu]
    solve = scalar_gamp if config.scalar_nodes else gamp
    res = GampResult(mu, cv, 0, True, 0.0)
    n_relin = 0
    for _ in range(config.relinearisations):
        n_relin += 1
        rows: list[list[tuple[int, Vec]]] = []
        y: list[float] = []
        var: list[float] = []
        for v in vids:
            m = pseudoranges.get(v)
            if m is None or not len(m):
                continue
            j = block[v]
            p = lin[j][pos_idx[v]]
            d = p - m.sat_pos
            r = np.linalg.norm(d, axis=1)
            u = d / r[:, None]
            for k in range(len(m)):
                coef = np.zeros(len(mu[j]))
                coef[pos_idx[v]] = u[k]
                coef[clock_idx[v][m.systems[k]]] = 1.0
                # rho_c = |p - s| + b ~ r + u'(p - p_lin) + b  =>  y = rho_c - r + u' p_lin
                rows.append([(j, coef)])
                y.append(float(m.rho_c[k] - r[k] + u[k] @ p))
                var.append(float(m.sigma[k] ** 2))
        for rr in ranges:
            ja, jb = block[rr.a], block[rr.b]
            d = lin[ja][pos_idx[rr.a]] - lin[jb][pos_idx[rr.b]]
            dist = float(np.linalg.norm(d))
            u = d / dist if dist > 0 else np.zeros(3)
            ca = np.zeros(len(mu[ja]))
            ca[pos_idx[rr.a]] = u
            cb = np.zeros(len(mu[jb]))
            cb[pos_idx[rr.b]] = -u
            rows.append([(ja, ca), (jb, cb)])
            y.append(rr.range_m - dist + float(u @ d))
            var.append(rr.sigma_m**2)
        if not rows:
            break
        res = solve(
            mu,
            cv,
            rows,
            np.array(y),
            np.array(var),
            config.damping,
            config.max_iterations,
            config.tolerance_m,
        )
        if not res.converged:
            break
        moved = max(
            float(np.max(np.abs(res.means[k][pos_idx[v]] - lin[k][pos_idx[v]]))) for v, k in block.items()
        )
        lin = [m.copy() for m in res.means]
        if moved < config.relinearisation_tolerance_m:
            break
    return res, n_relin


class GampCp(BaselineEstimator):
    """Estimator: per-vehicle predicted priors + damped GAMP over pseudoranges and ranges."""

    def __init__(self, config: GampConfig | None = None) -> None:
        super().__init__()
        self.config = config or GampConfig()
        self.uses_ranges = self.config.use_ranging
        # prediction, clock handling, gating, Doppler velocity and drift; no pseudorange update
        self.local = NonCpEkf(self.config.ekf, apply_pseudoranges=False)

    def solve(self, valid: ValidEpoch, out: EpochOutcome) -> None:
        self.local.solve(valid, out)
        if not out.estimates:
            return
        try:
            out.estimates = self._gamp(valid, out.estimates, out.rejected, out.counts)
        except Exception as exc:  # never raise on data: fall back to the exact local update
            # counted and said: a fallback on every epoch would otherwise pass for a weak method
            log.warning(
                "gamp-cp at %s: message passing failed (%s: %s); every vehicle takes its local EKF update",
                valid.time,
                type(exc).__name__,
                exc,
            )
            out.rejected["gamp_failure"] += 1
            out.estimates = self._local_update(out.estimates, out.counts)

    def _local_update(
        self, local: dict[str, VehicleEstimate], counts: Counter[str]
    ) -> dict[str, VehicleEstimate]:
        """The Non-CP EKF pseudorange update: what each vehicle has without message passing."""
        out = {}
        for v, e in local.items():
            f = self.local.filters[v]
            m = self.local.gated.get(v)
            if m is not None and len(m):
                rows = Rows(len(f.x))
                f.pseudorange_rows(rows, m)
                f.update(rows, range(len(rows.groups)))
                counts["pseudorange"] += len(m)
            out[v] = self._estimate(v, e, 0)
        return out

    def _estimate(self, v: str, e: VehicleEstimate, n_ranges: int) -> VehicleEstimate:
        f = self.local.filters[v]
        return dataclasses.replace(
            e,
            position_m=f.position(v),
            covariance_m2=f.position_cov(v),
            clocks_s={s: float(f.x[f.index[(v, f"b:{s}")]]) / C for s in f.clock_systems(v)},
            n_ranges=n_ranges,
        )

    def _gamp(
        self,
        valid: ValidEpoch,
        local: dict[str, VehicleEstimate],
        rejected: Counter[str],
        counts: Counter[str],
    ) -> dict[str, VehicleEstimate]:
        cfg = self.config
        filters = self.local.filters
        vids = sorted(local)
        means = {v: filters[v].x.copy() for v in vids}
        covs = {v: filters[v].P.copy() for v in vids}
        pidx = {v: filters[v].pos_idx(v) for v in vids}
        cidx = {v: {s: filters[v].index[(v, f"b:{s}")] for s in filters[v].clock_systems(v)} for v in vids}
        used: list[RangeRow] = []
        if cfg.use_ranging:
            gate = chi2_threshold(cfg.range_gate_probability, 1)
            for r in valid.ranges_between(set(vids)):
                a, b, rng, sg = r.a, r.b, r.range_m, r.sigma_or(cfg.range_sigma)
                d = means[a][pidx[a]] - means[b][pidx[b]]
                dist = float(np.linalg.norm(d))
                if dist <= 0:
                    rejected["range"] += 1
                    continue
                u = d / dist
                pa = covs[a][np.ix_(pidx[a], pidx[a])]
                pb = covs[b][np.ix_(pidx[b], pidx[b])]
                if (rng - dist) ** 2 / (sg**2 + float(u @ (pa + pb) @ u)) > gate:
                    rejected["range_gate"] += 1
                    continue
                used.append(RangeRow(a, b, rng, sg))
        res, n_relin = cooperative_gamp(means, covs, pidx, cidx, self.local.gated, used, cfg)
        counts["gamp_iterations"] += res.iterations
        counts["gamp_relinearisations"] += n_relin
        if not res.converged or not all(np.all(np.isfinite(m)) for m in res.means):
            rejected["gamp_not_converged"] += 1
            return self._local_update(local, counts)
        counts["pseudorange"] += sum(len(m) for m in self.local.gated.values())
        counts["range"] += len(used)
        n_ranges: Counter[str] = Counter()
        for rr in used:
            n_ranges[rr.a] += 1
            n_ranges[rr.b] += 1
        out: dict[str, VehicleEstimate] = {}
        for k, v in enumerate(vids):
            f = filters[v]
            f.x = res.means[k].copy()
            f.P = 0.5 * (res.covariances[k] + res.covariances[k].T)
            out[v] = self._estimate(v, local[v], n_ranges[v])
        return out
