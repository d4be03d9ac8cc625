"""DD-CP baseline: double differences on a known baseline, their covariance, pairs, the filter."""

from __future__ import annotations

from collections import Counter

import numpy as np
from support.static_scene import scene, validate_vehicle

from coplane.baselines.dd_cp import (
    DdCpConfig,
    DdCpEkf,
    common_references,
    dd_covariance,
    dd_model,
    double_differences,
    spanning_pairs,
)
from coplane.baselines.fleet_filter import EkfConfig
from coplane.baselines.measurements import VehicleMeasurements


def measurements(sc_epoch: object, vids: list[str]) -> dict[str, VehicleMeasurements]:
    out = {}
    for v in vids:
        m = validate_vehicle(v, sc_epoch.vehicles[v], sc_epoch.time, Counter())  # type: ignore[attr-defined]
        assert not isinstance(m, str)
        out[v] = m
    return out


def hand_made(vid: str, sigmas: dict[str, float], elevations: dict[str, float]) -> VehicleMeasurements:
    """Measurements with chosen receiver-specific sigmas and elevations (geometry irrelevant)."""
    sats = sorted(sigmas)
    n = len(sats)
    rng = np.random.default_rng(len(vid))
    return VehicleMeasurements(
        vid,
        sats,
        [s[0] for s in sats],
        rng.normal(0.0, 2.0e7, (n, 3)),
        rng.normal(2.2e7, 1e6, n),
        np.array([sigmas[s] for s in sats]),
        np.array([sigmas[s] for s in sats]),
        np.array([elevations[s] for s in sats]),
    )


def test_double_differences_recover_the_baseline_exactly_without_noise() -> None:
    """Per-satellite errors common to both receivers (3 m), different receiver clocks and
    inter-system biases: all cancel, and Gauss-Newton on the DDs alone returns the baseline."""
    sc = scene({"a": (0.0, 0.0, 0.0), "b": (25.0, 10.0, 1.5)}, 1, seed=11, noise=False, common_sigma=3.0)
    meas = measurements(sc.epochs[0], ["a", "b"])
    dds, _, _ = double_differences([("a", "b")], meas)
    assert len(dds) == 14 - 2  # 8 GPS + 6 BeiDou, one reference each
    pa = sc.truth["a"]
    pb = sc.truth["b"] + np.array([5.0, -3.0, 4.0])
    for _ in range(5):
        rows = [dd_model(dd, meas["a"], meas["b"], pa, pb) for dd in dds]
        h = np.array([r[2] for r in rows])
        nu = np.array([dd.value_m - r[0] for dd, r in zip(dds, rows, strict=True)])
        pb = pb + np.linalg.lstsq(h, nu, rcond=None)[0]
    assert np.linalg.norm(pb - sc.truth["b"]) < 1e-6
    # the undifferenced pseudoranges are 3 m off per satellite: an absolute fix is not this good
    m_b = meas["b"]
    resid = m_b.rho_c - np.linalg.norm(m_b.sat_pos - sc.truth["b"], axis=1)
    assert np.std(resid[np.array(m_b.systems) == "G"]) > 1.0


def test_dd_covariance_of_one_pair_shares_the_reference_terms() -> None:
    sa = {"G01": 0.5, "G02": 0.7, "G03": 1.1, "C06": 0.9, "C11": 1.3}
    sb = {"G01": 0.6, "G02": 0.4, "G03": 1.2, "C06": 0.8, "C11": 2.0}
    el = {"G01": 0.3, "G02": 1.2, "G03": 0.5, "C06": 0.9, "C11": 0.4}  # references: G02, C06
    meas = {"a": hand_made("a", sa, el), "b": hand_made("b", sb, el)}
    assert common_references(meas["a"], meas["b"]) == {"C": ("C06", ["C11"]), "G": ("G02", ["G01", "G03"])}
    dds, cols, m = double_differences([("a", "b")], meas)
    assert [(d.sat, d.ref) for d in dds] == [("C11", "C06"), ("G01", "G02"), ("G03", "G02")]
    r = dd_covariance(m, cols, meas)

    def v(s: str) -> float:
        return sa[s] ** 2 + sb[s] ** 2

    expected = np.array(
        [
            [v("C11") + v("C06"), 0.0, 0.0],
            [0.0, v("G01") + v("G02"), v("G02")],
            [0.0, v("G02"), v("G03") + v("G02")],
        ]
    )
    np.testing.assert_allclose(r, expected, rtol=1e-12)
    # the measured DD is M times the stacked undifferenced values
    stacked = np.array([meas[vid].rho_c[meas[vid].sats.index(s)] for vid, s in cols])
    np.testing.assert_allclose(m @ stacked, [d.value_m for d in dds], rtol=0, atol=1e-6)
    # ... so R_DD is the covariance of those DDs under independent receiver errors (Monte Carlo)
    rng = np.random.default_rng(0)
    sig = np.array([(sa if vid == "a" else sb)[s] for vid, s in cols])
    samples = (m @ (rng.normal(size=(len(cols), 200_000)) * sig[:, None])).T
    np.testing.assert_allclose(np.cov(samples.T), expected, rtol=0.02, atol=0.02)


def test_dd_covariance_couples_pairs_through_the_shared_vehicle() -> None:
    sig = {
        "a": {"G01": 0.5, "G02": 0.7, "G03": 1.1},
        "b": {"G01": 0.6, "G02": 0.4, "G03": 1.2},
        "c": {"G01": 0.9, "G02": 0.3, "G03": 0.8},
    }
    el = {"G01": 0.3, "G02": 1.2, "G03": 0.5}
    meas = {v: hand_made(v, sig[v], el) for v in sig}
    dds, cols, m = double_differences([("a", "b"), ("b", "c")], meas)
    r = dd_covariance(m, cols, meas)
    assert [(d.a, d.b, d.sat) for d in dds] == [
        ("a", "b", "G01"),
        ("a", "b", "G03"),
        ("b", "c", "G01"),
        ("b", "c", "G03"),
    ]
    sb = sig["b"]
    # DD_ab(i) = a_i - b_i - a_r + b_r and DD_bc(j) = b_j - c_j - b_r + c_r share -b_i + b_r / b_j - b_r
    assert np.isclose(r[0, 2], -(sb["G01"] ** 2) - sb["G02"] ** 2)
    assert np.isclose(r[0, 3], -(sb["G02"] ** 2))
    assert np.isclose(r[1, 3], -(sb["G03"] ** 2) - sb["G02"] ** 2)
    assert np.all(np.linalg.eigvalsh(r) > 0)  # a tree of pairs: no redundant DD
    # the third pair would make the set redundant (DD_ac = DD_ab + DD_bc): singular covariance
    _, cols3, m3 = double_differences([("a", "b"), ("b", "c"), ("a", "c")], meas)
    assert np.linalg.matrix_rank(dd_covariance(m3, cols3, meas)) < len(m3)


def test_pairs_are_a_minimum_spanning_tree_within_range() -> None:
    pos = {
        "a": np.array([0.0, 0.0, 0.0]),
        "b": np.array([10.0, 0.0, 0.0]),
        "c": np.array([25.0, 0.0, 0.0]),
        "d": np.array([5000.0, 0.0, 0.0]),
    }
    cands = [("a", "b"), ("a", "c"), ("a", "d"), ("b", "c"), ("b", "d"), ("c", "d")]
    assert spanning_pairs(pos, cands, 1000.0) == [("a", "b"), ("b", "c")]
    assert spanning_pairs(pos, cands, 1e4) == [("a", "b"), ("b", "c"), ("c", "d")]


def test_dd_cp_filter_gets_the_relative_position_from_biased_pseudoranges() -> None:
    """Noise-free pseudoranges with 2 m common-mode errors per satellite: the absolute positions
    are off, the relative one is recovered by the fused DDs."""
    offsets = {"a": (0.0, 0.0, 0.0), "b": (25.0, 10.0, 1.5), "c": (-30.0, 12.0, -0.5)}
    sc = scene(offsets, 15, seed=12, noise=False, common_sigma=2.0)
    est = DdCpEkf(DdCpConfig(ekf=EkfConfig(gate_probability=1e-12)))
    sols = [est.step(e) for e in sc.epochs]
    last = sols[-1]
    assert last.factor_counts["dd_pairs"] == 2 and last.factor_counts["dd_pseudorange"] == 2 * 12
    pa = last.estimates["a"].position_m
    for v in ("b", "c"):
        rel = last.estimates[v].position_m - pa
        assert np.linalg.norm(rel - (sc.truth[v] - sc.truth["a"])) < 0.02
    assert np.linalg.norm(pa - sc.truth["a"]) > 0.3  # the common-mode error stays in the absolute


def test_dd_cp_matches_non_cp_for_a_single_vehicle_and_never_raises() -> None:
    from coplane.baselines.non_cp import NonCpEkf

    sc = scene({"a": (0.0, 0.0, 0.0)}, 10, seed=13)
    dd, ekf = DdCpEkf(), NonCpEkf()
    for e in sc.epochs:
        s1, s2 = dd.step(e), ekf.step(e)
        np.testing.assert_allclose(s1.estimates["a"].position_m, s2.estimates["a"].position_m, atol=1e-9)
    # garbage epoch: wrong types everywhere; counted, not raised
    bad = sc.epochs[-1].__class__(sc.epochs[-1].time + 1.0, {"a": "nonsense"}, ("x",))  # type: ignore[arg-type]
    sol = dd.step(bad)
    assert "a" in sol.skipped and not sol.estimates
