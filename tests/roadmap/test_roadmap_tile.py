"""One tile's update rule: plane recovery, the slope prior, 1/sqrt(n), outliers, changes, decay."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from conftest import MakePass

from coplane.geo import ecef_to_geodetic, geodetic_to_ecef
from coplane.roadmap import PassEvidence, RoadMapConfig, TileKey, TilePlane, tile_centre

CFG = RoadMapConfig()
KEY = TileKey(26_780, 43_000)


def fresh() -> TilePlane:
    return TilePlane(KEY, 100.0)


def test_exact_plane_recovered_from_noise_free_passes(make_pass: MakePass) -> None:
    weak = dataclasses.replace(CFG, slope_prior_sigma=100.0)  # the prior is the only bias left
    for cfg, tol in ((weak, 1e-9), (CFG, 1e-3)):
        tile = fresh()
        for k, lane in enumerate([-3.5, 0.0, 3.5, -1.75, 1.75, 0.0]):
            upd = tile.add_pass(
                make_pass(a=0.42, b=0.05, c=-0.02, lane_n=lane, t=k, sigma=0.01, shared=False), cfg
            )
            assert upd.accepted and upd.change is None
        theta, _ = tile.estimate(cfg)
        np.testing.assert_allclose(theta, [0.42, 0.05, -0.02], atol=tol)
        h, s = tile.height_at(5.0, -2.0, cfg)
        assert h == pytest.approx(100.0 + 0.42 + 0.25 + 0.04, abs=10 * tol)
        assert s >= cfg.roughness_sigma_m  # never sharper than the road is flat
    assert tile.n_passes == 6 and tile.n_points == 6 * 19 and tile.version == 6 and tile.updated_s == 5.0


def test_first_pass_is_accepted_without_z_and_estimate_needs_offset_information(make_pass: MakePass) -> None:
    tile = fresh()
    with pytest.raises(ValueError, match="no offset information"):
        tile.estimate(CFG)
    upd = tile.add_pass(make_pass(a=3.0), CFG)
    assert upd.accepted and math.isnan(upd.z) and math.isnan(tile.recent[0].z)
    assert not tile.usable(CFG)
    tile.add_pass(make_pass(a=3.0, t=1.0), CFG)
    assert tile.usable(CFG)


def test_one_lane_keeps_the_cross_slope_sigma_at_the_prior(make_pass: MakePass) -> None:
    one, two = fresh(), fresh()
    for k in range(30):
        one.add_pass(make_pass(lane_n=1.5, t=k, vid=f"v{k}"), CFG)
        two.add_pass(make_pass(lane_n=1.5 if k % 2 else -1.75, t=k, vid=f"v{k}"), CFG)
    _, c1 = one.estimate(CFG)
    _, c2 = two.estimate(CFG)
    assert math.sqrt(c1[2, 2]) == pytest.approx(CFG.slope_prior_sigma, rel=1e-6)  # nothing learnt
    assert math.sqrt(c1[1, 1]) < 0.1 * CFG.slope_prior_sigma  # the grade along the lane is learnt
    assert math.sqrt(c2[2, 2]) < 0.5 * CFG.slope_prior_sigma  # a second lane gives the cross-slope
    # the one-lane tile is honest one lane over: its sigma grows with the prior's lever arm
    assert one.height_at(0.0, -5.0, CFG)[1] > 0.4 > one.height_at(0.0, 1.5, CFG)[1]


def test_offset_sigma_falls_as_one_over_sqrt_n(make_pass: MakePass) -> None:
    tile = fresh()
    sigma_pass = math.hypot(0.3, CFG.roughness_sigma_m)  # each pass: one error of this sigma
    ratios = []
    for k in range(64):
        # the covariance does not depend on the heights: noise-free passes that report sigma 0.3
        tile.add_pass(make_pass(lane_n=1.75 if k % 2 else -1.75, t=k, sigma=0.3, shared=False), CFG)
        n = k + 1
        if n in (4, 8, 16, 32, 64):
            _, cov = tile.estimate(CFG)
            ratios.append(math.sqrt(cov[0, 0]) / (sigma_pass / math.sqrt(n)))
    assert all(abs(r - 1.0) < 0.10 for r in ratios), ratios
    # however many points a pass has: one pass is one error
    big, small = fresh(), fresh()
    big.add_pass(make_pass(n_pts=200), CFG)
    small.add_pass(make_pass(n_pts=5), CFG)
    assert big.info[0, 0] == pytest.approx(small.info[0, 0])


def test_in_pass_outliers_are_dropped_before_the_fit(make_pass: MakePass) -> None:
    p = make_pass(a=0.0, sigma=0.05, shared=False, point_sigma=0.02)
    pts = p.points_enu.copy()
    pts[3, 2] += 6.0  # one NLOS epoch inside the pass
    tile = fresh()
    tile.add_pass(PassEvidence(p.vehicle_id, p.time_s, pts, p.sigmas_up_m), CFG)
    assert tile.n_points == pts.shape[0] - 1
    assert tile.height_at(0.0, 0.0, CFG)[0] == pytest.approx(100.0, abs=0.05)


def test_h_ref_shifts_the_points_into_the_tile_frame(make_pass: MakePass) -> None:
    p = make_pass(a=0.0, sigma=0.05, shared=False)
    pts = p.points_enu.copy()
    pts[:, 2] += 100.0 + 0.7  # heights above the ellipsoid, not above h0
    tile = fresh()
    tile.add_pass(PassEvidence("v1", 0.0, pts, p.sigmas_up_m, KEY, 0.0), CFG)
    assert tile.height_at(0.0, 0.0, CFG)[0] == pytest.approx(100.7, abs=1e-9)


def test_an_isolated_outlier_pass_is_rejected_and_is_not_a_change(make_pass: MakePass) -> None:
    tile = fresh()
    for k in range(20):
        assert tile.add_pass(make_pass(lane_n=(-1.0) ** k * 1.75, t=k, vid=f"v{k % 4}"), CFG).change is None
    before = tile.estimate(CFG)[0].copy()
    upd = tile.add_pass(make_pass(a=3.0, t=20.0, vid="bad"), CFG)
    assert not upd.accepted and upd.z > CFG.outlier_z and upd.change is None
    assert tile.outlier_passes == 1 and tile.n_passes == 20 and not tile.recent[-1].accepted
    np.testing.assert_allclose(
        tile.estimate(CFG)[0], before, rtol=1e-6, atol=1e-12
    )  # not added (1 s of decay)
    assert 0.0 < tile.cusum_pos <= 3.0 - CFG.cusum_k
    for k in range(21, 30):
        upd = tile.add_pass(make_pass(lane_n=(-1.0) ** k * 1.75, t=k, vid=f"v{k % 4}"), CFG)
        assert upd.accepted and upd.change is None
    assert tile.changes == 0


def test_a_step_is_detected_within_a_few_passes_and_relearned(make_pass: MakePass) -> None:
    tile = fresh()
    for k in range(20):
        assert tile.add_pass(make_pass(lane_n=(-1.0) ** k * 1.75, t=k, vid=f"v{k % 4}"), CFG).change is None
    old_h = tile.height_at(0.0, 0.0, CFG)[0]
    assert old_h == pytest.approx(100.0, abs=0.1)
    change = None
    for k in range(20, 30):  # the road was resurfaced: 0.5 m higher
        upd = tile.add_pass(make_pass(a=0.5, lane_n=(-1.0) ** k * 1.75, t=k, vid=f"v{k % 4}"), CFG)
        if upd.change is not None:
            change = upd.change
            break
    k_change = k
    assert change is not None and k_change - 20 + 1 <= 4, "detected within 4 passes"
    assert change.key == KEY and change.time_s == float(k) and 2 <= change.passes_used <= k - 20 + 1
    assert change.old_height_m == pytest.approx(old_h, abs=0.05)
    assert change.new_height_m == pytest.approx(100.5, abs=0.1)
    assert tile.height_at(0.0, 0.0, CFG)[0] == change.new_height_m
    assert (
        tile.changes == 1 and tile.cusum_pos == tile.cusum_neg == 0.0 and tile.n_passes == change.passes_used
    )
    for k in range(k_change + 1, k_change + 8):  # the re-learned tile accepts the new road
        upd = tile.add_pass(make_pass(a=0.5, lane_n=(-1.0) ** k * 1.75, t=k, vid=f"v{k % 4}"), CFG)
        assert upd.accepted and upd.change is None
    assert tile.height_at(0.0, 0.0, CFG)[0] == pytest.approx(100.5, abs=0.08)


def test_a_step_down_is_detected_too(make_pass: MakePass) -> None:
    tile = fresh()
    for k in range(10):
        tile.add_pass(make_pass(t=k, lane_n=(-1.0) ** k), CFG)
    changes = [tile.add_pass(make_pass(a=-1.0, t=10 + k, lane_n=(-1.0) ** k), CFG).change for k in range(4)]
    found = [c for c in changes if c is not None]
    assert len(found) == 1 and found[0].new_height_m == pytest.approx(99.0, abs=0.15)


def test_old_evidence_decays_with_the_half_life(make_pass: MakePass) -> None:
    hl = CFG.half_life_s
    tile = fresh()
    for k in range(5):
        tile.add_pass(make_pass(t=k, lane_n=(-1.0) ** k), CFG)
    info0, eta0 = tile.info.copy(), tile.eta.copy()
    p = make_pass(t=4.0 + hl, lane_n=1.0, sigma=0.1)
    tile.add_pass(p, CFG)
    new = fresh()
    new.add_pass(PassEvidence(p.vehicle_id, 0.0, p.points_enu, p.sigmas_up_m), CFG)
    np.testing.assert_allclose(tile.info, 0.5 * info0 + new.info, rtol=1e-12)
    np.testing.assert_allclose(tile.eta, 0.5 * eta0 + new.eta, rtol=1e-12)
    assert tile.updated_s == 4.0 + hl
    # a rejected pass advances updated_s but the interval before it is still decayed
    t2 = fresh()
    for k in range(5):
        t2.add_pass(make_pass(t=k, lane_n=(-1.0) ** k), CFG)
    info0 = t2.info.copy()
    assert not t2.add_pass(make_pass(a=5.0, t=4.0 + hl), CFG).accepted
    np.testing.assert_allclose(t2.info, 0.5 * info0, rtol=1e-12)
    # no decay with an infinite half-life
    forever = dataclasses.replace(CFG, half_life_s=math.inf)
    t3 = fresh()
    t3.add_pass(make_pass(t=0.0), forever)
    i1 = t3.info.copy()
    t3.add_pass(make_pass(t=1e9), forever)
    assert t3.info[0, 0] == pytest.approx(2 * i1[0, 0])


def test_recent_buffer_is_bounded_and_newest_last(make_pass: MakePass) -> None:
    cfg = dataclasses.replace(CFG, recent_passes=4)
    tile = fresh()
    for k in range(10):
        tile.add_pass(make_pass(t=float(k), vid=f"v{k}"), cfg)
    assert [p.vehicle_id for p in tile.recent] == ["v6", "v7", "v8", "v9"]


def test_plane_ecef_is_the_local_plane(make_pass: MakePass) -> None:
    tile = fresh()
    for k, lane in enumerate([-3.0, 0.0, 3.0]):
        tile.add_pass(make_pass(a=0.3, b=0.04, c=0.02, lane_n=lane, t=k, shared=False, sigma=0.01), CFG)
    normal, d = tile.plane_ecef(CFG)
    assert np.linalg.norm(normal) == pytest.approx(1.0)
    lat, lon = tile_centre(KEY, CFG.tile_size_m)
    up = geodetic_to_ecef(lat, lon, 1.0) - geodetic_to_ecef(lat, lon, 0.0)
    assert float(normal @ up) > 0.99  # upward
    for e, n in ((0.0, 0.0), (8.0, -6.0), (-9.0, 9.0)):
        h, _ = tile.height_at(e, n, CFG)
        # the ECEF point at local (e, n) on the surface: on the plane (to the local frame's curvature)
        origin = geodetic_to_ecef(lat, lon, 0.0)
        from coplane.geo import enu_rotation

        p = origin + enu_rotation(lat, lon).T @ np.array([e, n, h])
        assert abs(float(normal @ p) + d) < 1e-4
        assert ecef_to_geodetic(p)[2] == pytest.approx(h, abs=1e-4)
        assert tile.sigma_at_ecef(p, CFG) == pytest.approx(tile.height_at(e, n, CFG)[1], rel=1e-6)


def test_bad_passes_raise(make_pass: MakePass) -> None:
    p = make_pass()
    bad = p.points_enu.copy()
    bad[0, 0] = math.nan
    with pytest.raises(ValueError, match="non-finite"):
        fresh().add_pass(PassEvidence("v1", 0.0, bad, p.sigmas_up_m), CFG)
    with pytest.raises(ValueError, match="N >= 1"):
        fresh().add_pass(PassEvidence("v1", 0.0, np.empty((0, 3)), np.empty(0)), CFG)
