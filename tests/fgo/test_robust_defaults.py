"""The pieces of the methods' robust defaults (docs/fgo.md, "Robust defaults"), one at a time."""

from __future__ import annotations

import dataclasses
import math

import gtsam
import numpy as np
import pytest
from support.fgo_synthetic import error_stats, make_fleet, run

from coplane.fgo import factors as F
from coplane.fgo.config import FgoConfig
from coplane.geo import up_vector
from coplane.methods import get_method

NLOS = {"nlos_per_vehicle": 1, "nlos_bias": (10.0, 30.0)}


def test_motion_fallback_bounds_the_vertical_separately() -> None:
    """Covariance sigma^2 (I - u u^T) + sigma_up^2 u u^T: the vertical gets its own sigma."""
    at = np.array([-2.17e6, 4.38e6, 4.08e6])
    f = F.displacement_factor(1, 2, np.zeros(3), 2.0, at, 0.2)
    cov = np.linalg.inv(f.noiseModel().information())
    u = up_vector(at)
    assert math.isclose(float(u @ cov @ u), 0.04, rel_tol=1e-9)
    e = np.cross(u, [0.0, 0.0, 1.0])
    e /= np.linalg.norm(e)
    assert math.isclose(float(e @ cov @ e), 4.0, rel_tol=1e-9)


def test_height_does_not_run_away_in_an_outage() -> None:
    """v02 loses all GNSS for 10 epochs: its height is carried by the 0.2 m/s vertical fallback."""
    outage = range(15, 25)
    fleet = make_fleet(4, 32, seed=3, outages={"v02": outage}, **NLOS)
    for name, bound in (("non-cp", 3.0), ("mci", 3.0)):
        sols = run(fleet, get_method(name).fgo)
        up = [
            abs(float((fleet.enu @ (s.estimates["v02"].position_m - fleet.truth[k]["v02"]))[2]))
            for k, s in enumerate(sols)
            if k in outage
        ]
        assert max(up) < bound, (name, max(up))


def test_short_ranges_wait_for_both_tracks_to_settle() -> None:
    """Two vehicles a few metres apart whose SPP fixes are swapped stay swapped once a range holds
    them (planes pin the height, so they cannot pass each other). Measured on 4 NLOS seeds with the
    defaults: pc h 1.86 m without the warm-up, 0.61 m with it (mci 0.72 m)."""
    hs: dict[int, list[float]] = {0: [], 5: []}
    for seed in (0, 1, 2, 3):
        fleet = make_fleet(4, 40, seed=seed, **NLOS)
        for w in hs:
            cfg = dataclasses.replace(get_method("pc").fgo, range_warmup_epochs=w)
            sols = run(fleet, cfg)
            st = error_stats(fleet, sols, skip=5)
            hs[w].append(st.h_rmse)
            if w:
                assert sum(s.rejected.get("range_warmup", 0) for s in sols[:5]) > 0
                assert sum(s.rejected.get("range_warmup", 0) for s in sols[5:]) == 0
    assert max(hs[5]) < 1.0
    assert float(np.mean(hs[5])) < 0.6 * float(np.mean(hs[0]))


def test_a_far_off_first_fix_gets_its_short_ranges_at_once() -> None:
    """A first fix whose distance to a neighbour differs from their range by more than
    `range_warmup_max_m` is not a swap but a far-off fix, and the range pulls it in: the warm-up
    admits it (a vehicle started 28 m off in a canyon 4.7 m from another, city seed 11, docs/fgo.md).
    A vehicle whose track is settled anchors every range it has, so a new track next to it gets
    them too."""
    fleet = make_fleet(4, 12, seed=0, **NLOS)
    cfg = get_method("pc").fgo
    warm = cfg.range_warmup_epochs
    first = fleet.epochs[0]
    v01 = first.vehicles["v01"]
    assert v01.spp_position is not None
    moved = dataclasses.replace(v01, spp_position=v01.spp_position + 40.0 * fleet.enu[0])
    epochs = [dataclasses.replace(first, vehicles={**first.vehicles, "v01": moved}), *fleet.epochs[1:]]
    short = [r for r in first.ranges if r.range_m < cfg.range_warmup_max_m]
    with_v01 = sum("v01" in (r.a, r.b) for r in short)
    assert with_v01 > 0 and len(short) > with_v01
    held = run(fleet, cfg)[0].rejected.get("range_warmup", 0)
    assert held == len(short)
    assert run(fleet, cfg, epochs)[0].rejected.get("range_warmup", 0) == held - with_v01
    # v02 starts late (absent for the warm-up): the others are settled when it comes
    late = make_fleet(4, 12, seed=0, absent={"v02": range(warm + 1)}, **NLOS)
    came = late.epochs[warm + 1].ranges
    assert any("v02" in (r.a, r.b) and r.range_m < cfg.range_warmup_max_m for r in came)
    sols = run(late, cfg)
    assert sum(s.rejected.get("range_warmup", 0) for s in sols[warm + 1 :]) == 0


def test_reported_covariance_is_scaled_but_the_estimate_is_not() -> None:
    fleet = make_fleet(3, 12, seed=7)
    base = dataclasses.replace(get_method("mci").fgo, covariance_scale=1.0)
    a = run(fleet, base)
    b = run(fleet, dataclasses.replace(base, covariance_scale=3.5))
    for sa, sb in zip(a, b, strict=True):
        for vid, ea in sa.estimates.items():
            eb = sb.estimates[vid]
            assert np.array_equal(ea.position_m, eb.position_m)
            np.testing.assert_allclose(eb.covariance_m2, 3.5**2 * ea.covariance_m2, rtol=1e-12)


def test_gnc_on_the_window_rejects_nlos_that_plain_least_squares_absorbs() -> None:
    """`gnc="tls"` (GTSAM's GncLMOptimizer on the LM window, docs/fgo.md "GNC"): with the FDE and
    the kernel off, one 20-40 m NLOS satellite per vehicle pulls plain least squares by metres;
    GNC finds and drops it (measured: 5.7 -> 1.2 m; the defaults, FDE + Huber on the smoother,
    0.81 m). The defaults' bias ties are linear factors, which GNC must be told to allow."""
    fleet = make_fleet(4, 20, seed=11, nlos_per_vehicle=1, nlos_bias=(20.0, 40.0))
    base = dataclasses.replace(get_method("non-cp").fgo, solver="lm-window", robust=None, fde_k=None)
    plain = error_stats(fleet, run(fleet, base), skip=3)
    gnc = error_stats(fleet, run(fleet, dataclasses.replace(base, gnc="tls")), skip=3)
    assert gnc.h_rmse < 0.5 * plain.h_rmse, (gnc.h_rmse, plain.h_rmse)


def _robust_pseudoranges(block: object) -> list[bool]:
    """Whether each pseudorange factor of a state block has a robust noise model."""
    g = block.graph()  # type: ignore[attr-defined]
    out = []
    for i in range(g.size()):
        f = g.at(i)
        if isinstance(f, gtsam.PseudorangeFactor | gtsam.DifferentialPseudorangeFactor):
            out.append(isinstance(f.noiseModel(), gtsam.noiseModel.Robust))
    return out


def test_robust_warmup_leaves_a_tracks_first_epochs_without_the_kernel() -> None:
    """`robust_warmup_epochs` (opt-in, docs/fgo.md "A moving car against RTK"): the pseudoranges
    of a track's first N epochs are plain least squares, later ones take the kernel."""
    from coplane.fgo.engine import FusionEstimator

    fleet = make_fleet(2, 8, seed=1)
    cfg = dataclasses.replace(get_method("non-cp").fgo, robust_warmup_epochs=3)
    est = FusionEstimator(cfg)
    seen: dict[int, list[bool]] = {}
    for k, e in enumerate(fleet.epochs):
        est.step(e)
        for blocks in est._state.window.by_vehicle.values():
            b = blocks[-1]
            if b.step == k:
                seen.setdefault(k, []).extend(_robust_pseudoranges(b))
    assert all(seen[k] and not any(seen[k]) for k in (0, 1, 2)), seen
    assert all(seen[k] and all(seen[k]) for k in range(3, 8)), seen
    with pytest.raises(ValueError, match="robust_warmup_epochs"):
        FgoConfig(robust="huber", robust_warmup_epochs=-1)


def test_gnc_needs_the_lm_window_and_no_kernel() -> None:
    with pytest.raises(ValueError, match="gnc needs"):
        FgoConfig(gnc="tls", solver="isam2-fixed-lag")
    with pytest.raises(ValueError, match="gnc needs"):
        FgoConfig(gnc="tls", robust="huber")
    with pytest.raises(ValueError, match="unknown gnc"):
        FgoConfig(gnc="dcs")  # type: ignore[arg-type]


def test_a_kernel_on_planes_and_links_needs_a_kernel() -> None:
    with pytest.raises(ValueError, match="robust_planes_links needs a robust kernel"):
        FgoConfig(robust_planes_links=True)
    assert FgoConfig(robust="dcs", robust_planes_links=True).robust_tuning == 1.0


def test_robust_k_redundant_narrows_the_kernel_only_on_redundant_epochs() -> None:
    """`robust_k_redundant` (opt-in, docs/fgo.md "The kernel's corner"): an epoch with at least
    `robust_redundant_min` pseudoranges takes that k, a weaker one the usual `robust_k`."""
    cfg = FgoConfig(robust="huber", robust_k_redundant=0.5, robust_redundant_min=8)
    assert cfg.pseudorange_tuning(8) == 0.5
    assert cfg.pseudorange_tuning(7) == pytest.approx(1.345)
    assert FgoConfig(robust="huber").pseudorange_tuning(20) == pytest.approx(1.345)
    assert FgoConfig(robust=None, robust_k_redundant=0.5).pseudorange_tuning(20) is None
    with pytest.raises(ValueError, match="robust_redundant_min"):
        FgoConfig(robust="huber", robust_redundant_min=0)
    with pytest.raises(ValueError, match="robust_k_redundant"):
        FgoConfig(robust="huber", robust_k_redundant=-1.0)
