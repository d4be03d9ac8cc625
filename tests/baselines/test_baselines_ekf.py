"""Non-CP EKF baseline on hand-made receivers: batch equivalence, gating, clock jumps, outages.

The receivers come from `support.static_scene` (also used by the DD-CP and GAMP tests).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import replace

import numpy as np
import pytest
from support.static_scene import Scene, scene, validate_vehicle, with_vehicle

from coplane.baselines.fleet_filter import EkfConfig
from coplane.baselines.measurements import clock_residuals
from coplane.baselines.non_cp import NonCpEkf
from coplane.estimation.contract import EpochInput, VelocityObs
from coplane.gnss.constants import C

Vec = np.ndarray


QUIET = EkfConfig(
    accel_psd_h=1e-12,
    accel_psd_v=1e-12,
    clock_psd=1e-12,
    drift_psd=1e-12,
    isb_psd=1e-12,
    gate_probability=1e-12,
)


def batch_solution(sc: Scene, vid: str, cfg: EkfConfig) -> tuple[Vec, Vec, Vec, Vec]:
    """Gauss-Newton over all epochs for theta = [p0, v, d, b_G, b_C] with the EKF's own prior.

    Returns the final-epoch position, its covariance and the clocks (G, C) with their variances.
    """
    from collections import Counter

    m0 = validate_vehicle(vid, sc.epochs[0].vehicles[vid], sc.epochs[0].time, Counter())
    assert not isinstance(m0, str) and m0.spp is not None and m0.velocity is not None
    c0 = clock_residuals(m0, m0.spp)
    theta0 = np.concatenate([m0.spp, m0.velocity, [m0.drift or 0.0], [c0["C"], c0["G"]]])
    p0 = np.diag(
        [cfg.init_position_sigma_m**2] * 3
        + [cfg.init_velocity_sigma_mps**2] * 3
        + [cfg.init_drift_sigma_mps**2]
        + [cfg.init_clock_sigma_m**2] * 2
    )
    theta = theta0.copy()
    for _ in range(6):
        info = np.linalg.inv(p0)
        grad = info @ (theta0 - theta)
        for k, ep in enumerate(sc.epochs):
            m = validate_vehicle(vid, ep.vehicles[vid], ep.time, Counter())
            assert not isinstance(m, str) and m.velocity is not None and m.drift is not None
            p = theta[:3] + k * theta[3:6]
            for i in range(len(m)):
                ib = 7 if m.systems[i] == "C" else 8
                d = p - m.sat_pos[i]
                r = float(np.linalg.norm(d))
                h = np.zeros(9)
                h[:3] = d / r
                h[3:6] = k * d / r
                h[6] = k
                h[ib] = 1.0
                res = m.rho_c[i] - (r + theta[ib] + k * theta[6])
                w = 1.0 / m.sigma[i] ** 2
                info += w * np.outer(h, h)
                grad += w * h * res
            w = 1.0 / m.velocity_sigma**2
            info[3:6, 3:6] += w * np.eye(3)
            grad[3:6] += w * (m.velocity - theta[3:6])
            info[6, 6] += w
            grad[6] += w * (m.drift - theta[6])
        theta = theta + np.linalg.solve(info, grad)
    cov = np.linalg.inv(info)
    k = len(sc.epochs) - 1
    t = np.zeros((5, 9))
    t[:3, :3] = np.eye(3)
    t[:3, 3:6] = k * np.eye(3)
    t[3, 8] = t[4, 7] = 1.0  # G, C clocks at the last epoch
    t[3, 6] = t[4, 6] = k
    x = t @ theta
    cx = t @ cov @ t.T
    return x[:3], cx[:3, :3], x[3:], np.diag(cx)[3:]


def test_static_receiver_equals_batch_least_squares() -> None:
    """Without process noise the EKF is recursive least squares: the same estimate and covariance
    as one Gauss-Newton over every epoch with the same prior (linearisation differences only)."""
    sc = scene({"a": (0.0, 0.0, 0.0)}, 60, seed=3)
    ekf = NonCpEkf(QUIET)
    sols = [ekf.step(ep) for ep in sc.epochs]
    est = sols[-1].estimates["a"]
    p, cov, clocks, _ = batch_solution(sc, "a", QUIET)
    assert np.max(np.abs(est.position_m - p)) < 1e-4
    np.testing.assert_allclose(est.covariance_m2, cov, rtol=1e-3, atol=1e-6)
    assert abs(est.clocks_s["G"] * C - clocks[0]) < 1e-4 and abs(est.clocks_s["C"] * C - clocks[1]) < 1e-4
    # ... and it converges to the truth within its own uncertainty
    err = est.position_m - sc.truth["a"]
    assert float(err @ np.linalg.solve(est.covariance_m2, err)) < 16.27  # chi2(3) 99.9 %
    assert math.sqrt(np.trace(est.covariance_m2)) < 0.6  # 60 epochs x 14 satellites at 1 m
    assert not any(s.rejected for s in sols)
    # the reported covariance only shrinks (static, no process noise)
    tr = [float(np.trace(s.estimates["a"].covariance_m2)) for s in sols]
    assert all(b < a for a, b in itertools.pairwise(tr))


def test_gate_rejects_a_100_m_outlier() -> None:
    sc = scene({"a": (0.0, 0.0, 0.0)}, 40, seed=1)
    k = 30
    ep = sc.epochs[k]
    prs = list(ep.vehicles["a"].pseudoranges)
    prs[3] = replace(prs[3], rho_m=prs[3].rho_m + 100.0)
    bad = list(sc.epochs)
    bad[k] = with_vehicle(ep, "a", pseudoranges=tuple(prs))

    def run(cfg: EkfConfig, epochs: list[EpochInput]) -> tuple[Vec, dict[str, int]]:
        ekf = NonCpEkf(cfg)
        out = [ekf.step(e) for e in epochs]
        return out[k].estimates["a"].position_m, out[k].rejected

    without = list(sc.epochs)
    without[k] = with_vehicle(ep, "a", pseudoranges=tuple(prs[:3] + prs[4:]))
    clean, rej_clean = run(EkfConfig(), without)
    gated, rej = run(EkfConfig(), bad)
    ungated, _ = run(EkfConfig(gate_probability=1e-300), bad)  # threshold inf: no gate
    assert rej.get("pseudorange_gate", 0) == rej_clean.get("pseudorange_gate", 0) + 1 == 1
    assert np.linalg.norm(gated - clean) < 1e-9  # exactly as if the satellite were not there
    assert np.linalg.norm(ungated - clean) > 3.0  # what it would have done


def test_clock_jump_restarts_the_clock_not_the_position() -> None:
    sc = scene({"a": (0.0, 0.0, 0.0)}, 40, seed=2)
    epochs = []
    for k, ep in enumerate(sc.epochs):
        if k >= 20:  # receiver clock steered by 1 ms from epoch 20 on (both systems)
            prs = tuple(replace(o, rho_m=o.rho_m + C * 1e-3) for o in ep.vehicles["a"].pseudoranges)
            ep = with_vehicle(ep, "a", pseudoranges=prs)
        epochs.append(ep)
    ekf = NonCpEkf()
    sols = [ekf.step(e) for e in epochs]
    assert sols[20].rejected.get("clock_reset") == 2  # GPS and BeiDou clocks
    assert not any(s.rejected.get("clock_reset") for i, s in enumerate(sols) if i != 20)
    assert not any(s.rejected.get("reinit") for s in sols)
    for s in sols[20:]:
        assert np.linalg.norm(s.estimates["a"].position_m - sc.truth["a"]) < 2.0
    step = sols[-1].estimates["a"].clocks_s["G"] - sols[19].estimates["a"].clocks_s["G"]
    assert abs(step - 1e-3 - 20 * 30.0 / C) * C < 3.0  # the jump plus 20 s of 30 m/s drift


def test_outage_predicts_with_growing_covariance_and_recovers() -> None:
    sc = scene({"a": (0.0, 0.0, 0.0)}, 50, seed=4)
    out = range(20, 30)
    epochs = [
        with_vehicle(ep, "a", pseudoranges=(), velocity=None, spp_position=None, clock_drift_mps=None)
        if k in out
        else ep
        for k, ep in enumerate(sc.epochs)
    ]
    ekf = NonCpEkf()
    sols = [ekf.step(e) for e in epochs]
    assert all("a" in s.estimates for s in sols)  # prediction only, still reported
    assert all(not sols[k].estimates["a"].has_gnss_fix for k in out)
    tr = [float(np.trace(sols[k].estimates["a"].covariance_m2)) for k in range(19, 30)]
    assert all(b > a for a, b in itertools.pairwise(tr))
    assert tr[-1] > 5 * tr[0]
    assert sols[30].estimates["a"].has_gnss_fix
    assert np.linalg.norm(sols[35].estimates["a"].position_m - sc.truth["a"]) < 1.5
    assert np.trace(sols[35].estimates["a"].covariance_m2) < tr[-1] / 5


def test_bad_inputs_are_counted_never_raised_and_runs_are_deterministic() -> None:
    sc = scene({"a": (0.0, 0.0, 0.0), "b": (20.0, 5.0, 0.0)}, 12, seed=5)
    ep = sc.epochs[5]
    prs = list(ep.vehicles["a"].pseudoranges)
    prs[0] = replace(prs[0], rho_m=math.nan)
    prs[1] = replace(prs[1], sigma_m=-1.0)
    prs[2] = replace(prs[2], sat_pos_m=np.array([1.0, 2.0, 3.0]))
    prs.append(prs[4])  # duplicate satellite
    epochs = list(sc.epochs)
    epochs[5] = with_vehicle(ep, "a", pseudoranges=tuple(prs), velocity=VelocityObs(np.full(3, np.inf), 0.1))
    epochs[6] = with_vehicle(epochs[6], "b", vehicle_id="zz")  # id mismatch
    epochs.insert(8, epochs[7])  # same time again: the whole epoch is skipped

    def run() -> list[tuple[object, ...]]:
        ekf = NonCpEkf()
        out = []
        for e in epochs:
            s = ekf.step(e)
            out.append(
                (
                    s.rejected,
                    s.skipped,
                    {v: (e.position_m.tobytes(), e.covariance_m2.tobytes()) for v, e in s.estimates.items()},
                )
            )
        return out

    first = run()
    assert first[5][0]["pseudorange"] == 4 and first[5][0]["velocity"] == 1
    assert first[6][0]["vehicle"] == 1 and "b" in first[6][1]
    assert first[8][0] == {"epoch": 1} and not first[8][2]
    assert first == run()  # bitwise identical


def test_vehicle_without_spp_is_skipped_until_it_has_one() -> None:
    sc = scene({"a": (0.0, 0.0, 0.0)}, 5, seed=6)
    epochs = [with_vehicle(e, "a", spp_position=None) if k < 2 else e for k, e in enumerate(sc.epochs)]
    ekf = NonCpEkf()
    sols = [ekf.step(e) for e in epochs]
    assert "SPP" in sols[0].skipped["a"] and "a" not in sols[1].estimates
    assert "a" in sols[2].estimates


@pytest.mark.parametrize("name", ["non-cp-ekf", "dd-cp", "gamp-cp"])
def test_registered_methods_build_estimators(name: str) -> None:
    from coplane.methods import get_method

    spec = get_method(name)
    assert spec.planes == "none" and spec.factory is not None
    assert spec.uses_ranging == (name == "gamp-cp")
    sc = scene({"a": (0.0, 0.0, 0.0), "b": (30.0, 0.0, 0.0)}, 3, seed=7)
    est = spec.build_estimator()
    sols = [est.step(e) for e in sc.epochs]
    assert set(sols[-1].estimates) == {"a", "b"}
