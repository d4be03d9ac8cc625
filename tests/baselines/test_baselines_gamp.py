"""GAMP-CP baseline: fixed point = joint least squares, = the factor graph, damping, the estimator."""

from __future__ import annotations

import dataclasses
import math

import gtsam
import numpy as np
import pytest
from support.fgo_synthetic import error_stats, make_fleet

from coplane.baselines.dd_cp import DdCpEkf
from coplane.baselines.gamp_cp import GampConfig, GampCp, RangeRow, cooperative_gamp, gamp, scalar_gamp
from coplane.baselines.non_cp import NonCpEkf
from coplane.estimation.contract import RangeObs
from coplane.fgo import factors as F

Vec = np.ndarray


def joint_lmmse(
    means: list[Vec], covs: list[Vec], rows: list[list[tuple[int, Vec]]], y: Vec, var: Vec
) -> tuple[Vec, Vec]:
    """(V^-1 + A' R^-1 A)^-1 (V^-1 mu + A' R^-1 y): the answer GAMP's fixed point must give."""
    off = np.cumsum([0] + [len(m) for m in means])
    a = np.zeros((len(y), off[-1]))
    for i, row in enumerate(rows):
        for j, c in row:
            a[i, off[j] : off[j + 1]] += c
    v = np.zeros((off[-1], off[-1]))
    for j, c in enumerate(covs):
        v[off[j] : off[j + 1], off[j] : off[j + 1]] = c
    vi = np.linalg.inv(v)
    p = np.linalg.inv(vi + a.T @ (a / var[:, None]))
    return p @ (vi @ np.concatenate(means) + a.T @ (y / var)), p


def triangle(seed: int) -> tuple[list[Vec], list[Vec], list[Vec], list[tuple[int, int, float]]]:
    """Three nodes ~20 m apart, full-covariance 2-5 m priors, three 0.3 m ranges."""
    rng = np.random.default_rng(seed)
    truth = [np.array([0.0, 0.0, 0.0]), np.array([20.0, 3.0, 0.5]), np.array([8.0, 18.0, -0.3])]
    means, covs = [], []
    for t in truth:
        q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        c = q @ np.diag(rng.uniform(2.0, 5.0, 3) ** 2) @ q.T
        means.append(t + np.linalg.cholesky(c) @ rng.normal(size=3))
        covs.append(c)
    ranges = [
        (a, b, float(np.linalg.norm(truth[a] - truth[b]) + rng.normal(0.0, 0.3)))
        for a, b in ((0, 1), (1, 2), (0, 2))
    ]
    return truth, means, covs, ranges


@pytest.mark.parametrize("damping", [1.0, 0.5])
def test_gamp_fixed_point_is_the_joint_least_squares_solution(damping: float) -> None:
    _, means, covs, ranges = triangle(1)
    rows, y = [], []
    for a, b, d in ranges:  # linearised once at the prior means: a linear-Gaussian problem
        u = (means[a] - means[b]) / np.linalg.norm(means[a] - means[b])
        rows.append([(a, u), (b, -u)])
        y.append(d - float(np.linalg.norm(means[a] - means[b])) + float(u @ (means[a] - means[b])))
    var = np.full(3, 0.09)
    res = gamp(means, covs, rows, np.array(y), var, damping=damping, max_iterations=2000, tolerance=1e-9)
    exact, p = joint_lmmse(means, covs, rows, np.array(y), var)
    assert res.converged
    assert np.max(np.abs(np.concatenate(res.means) - exact)) < 1e-6
    # GAMP's variances are an approximation (a loopy graph): measured within 0.75-2.1 of the exact
    # marginals (generalised eigenvalues) over seeds 0-5 of this triangle
    for j in range(3):
        li = np.linalg.inv(np.linalg.cholesky(p[3 * j : 3 * j + 3, 3 * j : 3 * j + 3]))
        ev = np.linalg.eigvalsh(li @ res.covariances[j] @ li.T)
        assert ev.min() > 0.5 and ev.max() < 3.0


def test_relinearised_gamp_matches_the_factor_graph() -> None:
    """Priors + nonlinear ranges: GAMP with relinearisation = GTSAM LM on the same factors."""
    _, means, covs, ranges = triangle(2)
    names = ["a", "b", "c"]
    cfg = GampConfig(
        tolerance_m=1e-9, relinearisation_tolerance_m=1e-8, relinearisations=20, max_iterations=5000
    )
    res, n_relin = cooperative_gamp(
        dict(zip(names, means, strict=True)),
        dict(zip(names, covs, strict=True)),
        {v: [0, 1, 2] for v in names},
        {v: {} for v in names},
        {},
        [RangeRow(names[a], names[b], d, 0.3) for a, b, d in ranges],
        cfg,
    )
    assert res.converged and n_relin >= 2
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    for j, (m, c) in enumerate(zip(means, covs, strict=True)):
        graph.add(F.position_prior(j, m, c))
        values.insert(j, gtsam.Point3(*m))
    for a, b, d in ranges:
        graph.add(F.range_factor(a, b, d, 0.3, None, None))
    lm = gtsam.LevenbergMarquardtParams()
    lm.setRelativeErrorTol(1e-14)
    lm.setAbsoluteErrorTol(1e-14)
    out = gtsam.LevenbergMarquardtOptimizer(graph, values, lm).optimize()
    for j in range(3):
        assert np.max(np.abs(res.means[j] - np.asarray(out.atPoint3(j)))) < 1e-5


def clock_network(
    seed: int, n_sat: int = 30
) -> tuple[list[Vec], list[Vec], list[list[tuple[int, Vec]]], Vec, Vec]:
    """Three receivers with p, b_GPS, b_BDS: 1 m position priors, 1.2 m clock priors correlated
    0.97 (one oscillator), n_sat pseudorange rows each (half per system) and three ranges."""
    rng = np.random.default_rng(seed)
    c = np.zeros((5, 5))
    c[:3, :3] = np.eye(3)
    c[3:, 3:] = 1.44 * np.array([[1.0, 0.97], [0.97, 1.0]])
    truth = [np.array([10.0 * j, 0.0, 0.0, 100.0 + j, 120.0 + j]) for j in range(3)]
    means = [t + np.linalg.cholesky(c) @ rng.normal(size=5) for t in truth]
    rows: list[list[tuple[int, Vec]]] = []
    y, var = [], []
    for j in range(3):
        for k in range(n_sat):
            el, az = rng.uniform(0.25, 1.4), rng.uniform(0, 2 * math.pi)
            u = -np.array([math.cos(el) * math.sin(az), math.cos(el) * math.cos(az), math.sin(el)])
            a = np.concatenate([u, [1.0, 0.0] if k % 2 == 0 else [0.0, 1.0]])
            rows.append([(j, a)])
            y.append(a @ truth[j] + rng.normal())
            var.append(1.0)
    for a_, b_ in ((0, 1), (1, 2), (0, 2)):
        d = truth[a_][:3] - truth[b_][:3]
        ca = np.concatenate([d / np.linalg.norm(d), [0.0, 0.0]])
        rows.append([(a_, ca), (b_, -ca)])
        y.append(ca @ truth[a_] - ca @ truth[b_] + rng.normal(0.0, 0.3))
        var.append(0.09)
    return means, [c.copy() for _ in range(3)], rows, np.array(y), np.array(var)


def test_damping_keeps_gamp_stable() -> None:
    """Textbook scalar GAMP diverges undamped on GNSS rows with one-oscillator clocks (A is far
    from zero-mean i.i.d.); damped it converges to the joint least-squares answer. The
    vector-node GAMP of the estimator converges either way, to the same answer."""
    args = clock_network(0)
    exact, _ = joint_lmmse(*args)
    undamped = scalar_gamp(*args, damping=1.0, max_iterations=300, tolerance=1e-6)
    assert not undamped.converged
    assert not math.isfinite(undamped.last_change) or undamped.last_change > 1e6  # blew up
    damped = scalar_gamp(*args, damping=0.5, max_iterations=1000, tolerance=1e-7)
    assert damped.converged
    assert np.max(np.abs(np.concatenate(damped.means) - exact)) < 1e-4
    for beta in (1.0, 0.5):
        vec = gamp(*args, damping=beta, max_iterations=1000, tolerance=1e-7)
        assert vec.converged
        assert np.max(np.abs(np.concatenate(vec.means) - exact)) < 1e-5


def test_gamp_cp_uses_the_ranges() -> None:
    """Synthetic fleet (tests/support/fgo_synthetic.py): ranges make GAMP-CP better than the same
    vehicles alone, and carry a vehicle through a GNSS outage."""
    fleet = make_fleet(4, 30, seed=3, pr_sigma=3.0, with_planes=False, outages={"v02": range(15, 22)})
    gamp_cp, alone, no_ir = GampCp(), NonCpEkf(), GampCp(GampConfig(use_ranging=False))
    s_gamp = [gamp_cp.step(e) for e in fleet.epochs]
    s_alone = [alone.step(e) for e in fleet.epochs]
    s_noir = [no_ir.step(e) for e in fleet.epochs]
    assert all(not s.rejected.get("gamp_not_converged") for s in s_gamp)
    assert s_gamp[-1].factor_counts["range"] == 6 and s_gamp[-1].estimates["v01"].n_ranges == 3
    assert "range" not in s_noir[-1].factor_counts
    e_gamp, e_alone = error_stats(fleet, s_gamp, skip=5), error_stats(fleet, s_alone, skip=5)
    assert e_gamp.h_rmse < 0.8 * e_alone.h_rmse
    out = range(15, 22)
    worst = max(np.linalg.norm(fleet.enu_error(k, "v02", s_gamp[k].estimates["v02"].position_m)) for k in out)
    worst_alone = max(
        np.linalg.norm(fleet.enu_error(k, "v02", s_alone[k].estimates["v02"].position_m)) for k in out
    )
    assert worst < worst_alone


ESTIMATORS = {"non-cp-ekf": NonCpEkf, "dd-cp": DdCpEkf, "gamp-cp": GampCp}


@pytest.mark.parametrize("name", sorted(ESTIMATORS))
def test_estimators_are_deterministic_and_survive_garbage(name: str) -> None:
    """Bitwise identical reruns; randomly corrupted inputs are counted, never raised."""
    fleet = make_fleet(3, 12, seed=5, with_planes=False)
    rng = np.random.default_rng(0)
    epochs = []
    for k, ep in enumerate(fleet.epochs):
        if k % 3 == 2:  # corrupt: NaN / inf / absurd values, bad ranges
            vehicles = {}
            for vid, vin in ep.vehicles.items():
                prs = list(vin.pseudoranges)
                for i in rng.choice(len(prs), size=3, replace=False):
                    field_ = ["rho_m", "sigma_m", "sat_clock_s"][int(rng.integers(3))]
                    prs[int(i)] = dataclasses.replace(
                        prs[int(i)], **{field_: float(rng.choice([np.nan, np.inf, -1.0, 1e12]))}
                    )
                vehicles[vid] = dataclasses.replace(
                    vin, pseudoranges=tuple(prs), clock_drift_mps=float("nan")
                )
            ranges = (*ep.ranges, RangeObs("v01", "v01", 5.0, 0.3), RangeObs("v01", "v02", float("nan"), 0.3))
            ep = dataclasses.replace(ep, vehicles=vehicles, ranges=ranges)
        epochs.append(ep)

    def run() -> list[tuple[object, ...]]:
        est = ESTIMATORS[name]()
        out = []
        for e in epochs:
            s = est.step(e)
            out.append(
                (
                    s.rejected,
                    s.skipped,
                    {v: x.position_m.tobytes() + x.covariance_m2.tobytes() for v, x in s.estimates.items()},
                )
            )
        return out

    first = run()
    assert first == run()
    assert all(len(o[2]) == 3 for o in first)
    total = {k: sum(o[0].get(k, 0) for o in first) for k in ("pseudorange", "clock_drift", "range")}
    assert 24 <= total["pseudorange"] <= 36  # 3 per vehicle and corrupted epoch (a few stay plausible)
    assert total["clock_drift"] == 4 * 3
    assert total["range"] == (4 * 2 if name == "gamp-cp" else 0)  # only GAMP reads the ranges
