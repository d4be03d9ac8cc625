"""Availability detection (eqs. 14-16), RANSAC fault exclusion (Algorithm 1), RoadPlane."""

from __future__ import annotations

import json
import math
import typing
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from coplane.geo import enu_to_ecef, geodetic_to_ecef, up_vector
from coplane.messages import PlaneStatusName
from coplane.plane import (
    PlaneConfig,
    PlaneStatus,
    PositionHistory,
    RoadPlane,
    construct_plane,
    ransac_inliers,
)

REF = geodetic_to_ecef(math.radians(39.98), math.radians(116.31), 50.0)  # Zhongguancun, Beijing
UP = up_vector(REF)
CFG = PlaneConfig()
H = 1.6


def road_enu(
    n: int = 20,
    lanes: tuple[float, ...] = (-1.75, 1.75),
    length: float = 100.0,
    grade: float = 0.0,
    crest_radius: float | None = None,
    noise: float = 0.0,
    rng: np.random.Generator | None = None,
) -> np.ndarray:
    """Road points in ENU about REF: along north, lanes cycled, optional grade or crest, noise."""
    y = np.linspace(-length / 2, length / 2, n)
    x = np.array([lanes[i % len(lanes)] for i in range(n)])
    z = grade * y
    if crest_radius is not None:
        z = z - y**2 / (2 * crest_radius)
    enu = np.c_[x, y, z]
    if noise > 0:
        assert rng is not None
        enu = enu + rng.normal(0.0, noise, enu.shape)
    return enu


def ecef(enu: np.ndarray) -> np.ndarray:
    return enu_to_ecef(enu, REF)


def with_outliers(k: int, rng: np.random.Generator, n: int = 20) -> tuple[np.ndarray, np.ndarray]:
    """n points of a level two-lane road with k of them lifted 10-50 m (random which, random sign)."""
    enu = road_enu(n, noise=0.1, rng=rng)
    bad = np.zeros(n, dtype=bool)
    bad[rng.choice(n, size=k, replace=False)] = True
    enu[bad, 2] += rng.uniform(10.0, 50.0, k) * rng.choice([-1.0, 1.0], k)
    return ecef(enu), bad


def tilt_from_up_deg(p: RoadPlane) -> float:
    return math.degrees(math.acos(min(1.0, float(p.normal @ UP))))


def _rows(a: np.ndarray) -> set[tuple[float, ...]]:
    return {tuple(r) for r in np.round(a, 6)}


# -- availability ---------------------------------------------------------------------------


def test_clean_road_is_available_with_residual_sigma() -> None:
    rng = np.random.default_rng(1)
    pts = ecef(road_enu(20, noise=0.2, rng=rng))
    p = construct_plane(pts, H, CFG, rng)
    assert p.status is PlaneStatus.AVAILABLE and p.available and p.reason is None
    assert (p.n_points_initial, p.n_points_used, p.excluded) == (20, 20, 0)
    assert tilt_from_up_deg(p) < 3.0
    # sigma rule: RMS of the used points' distances to their plane, floored at min_sigma_m
    dist = np.abs((pts - p.centroid) @ p.normal)
    assert p.residual_rms_m == pytest.approx(float(np.sqrt(np.mean(dist**2))))
    assert p.residual_max_m == pytest.approx(float(dist.max()))
    assert p.sigma_m == pytest.approx(max(p.residual_rms_m, CFG.min_sigma_m))
    assert p.sigma_m > CFG.min_sigma_m  # 0.2 m noise is above the 5 cm floor
    # antenna plane h above the road plane, factor form of eq. (24)
    assert p.d_antenna == pytest.approx(p.d_road - H)
    assert p.constraint_error(p.centroid + H * p.normal) == pytest.approx(0.0, abs=1e-6)
    assert p.p_d_prime == p.d_antenna
    np.testing.assert_array_equal(p.u_pc, -p.normal)


def test_sigma_floor_for_an_exact_plane() -> None:
    p = construct_plane(ecef(road_enu(20)), H, CFG, np.random.default_rng(0))
    assert p.status is PlaneStatus.AVAILABLE
    assert p.residual_rms_m < 1e-6
    assert p.sigma_m == CFG.min_sigma_m


def test_status_values_are_the_wire_names() -> None:
    assert {s.value for s in PlaneStatus} == set(typing.get_args(PlaneStatusName))


def test_too_few_points_rejected_but_fit_reported() -> None:
    rng = np.random.default_rng(2)
    p = construct_plane(ecef(road_enu(9, noise=0.1, rng=rng)), H, CFG, rng)
    assert p.status is PlaneStatus.UNAVAILABLE
    assert p.reason == "too-few-points: 9 < 15"
    assert np.all(np.isfinite(p.normal)) and p.n_points_used == 9  # still shown for plots
    p0 = construct_plane(np.empty((0, 3)), H, CFG, rng)
    assert p0.status is PlaneStatus.UNAVAILABLE and p0.reason == "no fitting points"


# -- fault exclusion ------------------------------------------------------------------------


@pytest.mark.parametrize("k", [1, 3, 5])
def test_outliers_excluded(k: int) -> None:
    rng = np.random.default_rng(100 + k)
    pts, bad = with_outliers(k, rng)
    p = construct_plane(pts, H, CFG, rng)
    assert p.status is PlaneStatus.AVAILABLE_AFTER_FE, p.reason
    assert p.excluded == k and p.n_points_used == 20 - k
    assert _rows(p.points_excluded) == _rows(pts[bad])
    assert not (_rows(p.points_used) & _rows(pts[bad]))
    assert p.reason == f"fault exclusion removed {k} of 20 points"
    assert tilt_from_up_deg(p) < 3.0  # cross-slope sigma ~ 0.1 m / (1.75 m * sqrt(20)) = 0.7 deg
    assert abs(float((REF - p.centroid) @ p.normal)) < 0.2  # the true road (height 0) is on the plane


def test_outliers_excluded_over_many_seeds() -> None:
    """Safety over 300 seeds: never an available plane with an outlier in it; RANSAC with the
    paper's 7 iterations succeeds at least as often as 1 - (1 - C(15,3)/C(20,3))^7 = 0.97 allows."""
    ok = 0
    for seed in range(300):
        rng = np.random.default_rng(seed)
        k = 1 + seed % 5
        pts, bad = with_outliers(k, rng)
        p = construct_plane(pts, H, CFG, rng)
        if p.available:
            assert not (_rows(p.points_used) & _rows(pts[bad])), seed
            assert p.residual_max_m <= CFG.t_f_m
            ok += 1
    assert ok >= 0.95 * 300


@pytest.mark.parametrize("seed", range(10))
def test_more_outliers_than_allowed_is_unavailable(seed: int) -> None:
    rng = np.random.default_rng(seed)
    pts, _ = with_outliers(8, rng)
    p = construct_plane(pts, H, CFG, rng)
    assert p.status is PlaneStatus.UNAVAILABLE
    assert p.reason is not None and "after FE" in p.reason


def test_no_fe_ablation_uses_the_contaminated_plane() -> None:
    rng = np.random.default_rng(105)
    pts, bad = with_outliers(5, rng)
    no_fe = replace(CFG, fault_exclusion=False)
    p = construct_plane(pts, H, no_fe, rng)
    assert p.status is PlaneStatus.AVAILABLE and p.reason is None
    assert (p.n_points_used, p.excluded) == (20, 0)
    clean = pts[~bad]
    assert np.abs((clean - p.centroid) @ p.normal).max() > 1.0  # off the true road
    with_fe = construct_plane(pts, H, CFG, np.random.default_rng(105))
    assert with_fe.status is PlaneStatus.AVAILABLE_AFTER_FE


def test_no_fe_needs_only_three_non_collinear_points() -> None:
    no_fe = replace(CFG, fault_exclusion=False)
    rng = np.random.default_rng(0)
    p = construct_plane(ecef(road_enu(3)), H, no_fe, rng)
    assert p.status is PlaneStatus.AVAILABLE
    assert p.sigma_m == no_fe.min_sigma_m  # exact fit: the floor
    line = construct_plane(ecef(road_enu(10, lanes=(0.0,))), H, no_fe, rng)
    assert line.status is PlaneStatus.UNAVAILABLE and line.reason is not None
    assert line.reason.startswith("degenerate")
    assert np.isnan(line.normal).all() and math.isnan(line.sigma_m)


def test_ransac_follows_algorithm_1() -> None:
    rng = np.random.default_rng(7)
    pts, bad = with_outliers(4, rng)
    inl = ransac_inliers(pts, CFG, np.random.default_rng(3))
    assert inl is not None and inl.dtype == bool and inl.shape == (20,)
    np.testing.assert_array_equal(inl, ~bad)
    # all-inlier data (no collinear triple, none steep) stops after the first triple: 3 draws
    xy = np.random.default_rng(1).uniform([-10, -50], [10, 50], (20, 2))
    clean = ecef(np.c_[xy, 0.01 * xy[:, 0]])
    g1, g2 = np.random.default_rng(5), np.random.default_rng(5)
    inl = ransac_inliers(clean, CFG, g1)
    assert inl is not None and inl.all()
    g2.choice(20, size=3, replace=False)
    assert g1.integers(1 << 30) == g2.integers(1 << 30)
    # steep triples are not hypotheses: a wall of points gives none with the tilt rule
    wall = ecef(np.c_[np.zeros(20), xy[:, 1], xy[:, 0]])
    assert ransac_inliers(wall, CFG, rng) is None
    assert ransac_inliers(wall, replace(CFG, max_tilt_deg=None), rng) is not None
    # only collinear triples: no plane at all
    assert ransac_inliers(ecef(road_enu(20, lanes=(0.0,))), CFG, rng) is None


# -- geometry: curves, grades, lines ------------------------------------------------------------


@pytest.mark.parametrize("seed", range(20))
def test_sharp_crest_is_unavailable(seed: int) -> None:
    rng = np.random.default_rng(seed)
    enu = road_enu(20, lanes=(-5.25, -1.75, 1.75, 5.25), crest_radius=50.0, noise=0.05, rng=rng)
    p = construct_plane(ecef(enu), H, CFG, rng)
    assert p.status is PlaneStatus.UNAVAILABLE
    assert p.reason is not None


def test_constant_grade_is_available_with_its_slope() -> None:
    rng = np.random.default_rng(4)
    enu = road_enu(20, lanes=(-1.75, 1.75), grade=0.05, noise=0.05, rng=rng)
    p = construct_plane(ecef(enu), H, CFG, rng)
    assert p.status is PlaneStatus.AVAILABLE
    assert p.tilt_deg == pytest.approx(math.degrees(math.atan(0.05)), abs=0.3)


def test_t_f_decides_how_much_curvature_passes() -> None:
    # R = 300 m crest over 100 m: LS residual ~ L^2/(12 R) = 2.8 m, under the paper's 5 m
    enu = road_enu(20, lanes=(-5.25, -1.75, 1.75, 5.25), crest_radius=300.0)
    p5 = construct_plane(ecef(enu), H, CFG, np.random.default_rng(0))
    assert p5.status is PlaneStatus.AVAILABLE and 2.0 < p5.residual_max_m < 5.0
    p1 = construct_plane(ecef(enu), H, replace(CFG, t_f_m=1.0), np.random.default_rng(0))
    assert p1.status is PlaneStatus.UNAVAILABLE


def test_single_lane_crest_vertical_plane_needs_the_tilt_rule() -> None:
    enu = road_enu(20, lanes=(0.0,), crest_radius=200.0)  # all points in one vertical plane
    p = construct_plane(ecef(enu), H, CFG, np.random.default_rng(0))
    assert p.status is PlaneStatus.UNAVAILABLE and p.reason is not None and "tilt" in p.reason
    paper_only = replace(CFG, max_tilt_deg=None, min_singular_ratio=1.0)
    q = construct_plane(ecef(enu), H, paper_only, np.random.default_rng(0))
    assert q.status is PlaneStatus.AVAILABLE and q.tilt_deg > 80.0  # eq. (16) alone accepts a wall


def test_single_lane_exactly_collinear_is_degenerate() -> None:
    p = construct_plane(ecef(road_enu(20, lanes=(0.0,))), H, CFG, np.random.default_rng(0))
    assert p.status is PlaneStatus.UNAVAILABLE
    assert p.reason is not None and p.reason.startswith("degenerate") and "collinear" in p.reason


def test_single_lane_with_noise_is_ill_conditioned_multi_lane_is_not() -> None:
    # one lane, each point moved 0.3 m across or up/down in a direction that turns 7 x 18 deg
    # per point: the cross-section scatter is isotropic, so s2 ~ s3 and the cross-slope is noise
    ang = np.arange(20) * 7 * 2 * math.pi / 20
    wobble = 0.3 * np.c_[np.cos(ang), np.zeros(20), np.sin(ang)]
    one = construct_plane(ecef(road_enu(20, lanes=(0.0,)) + wobble), H, CFG, np.random.default_rng(0))
    assert one.status is PlaneStatus.UNAVAILABLE
    assert one.reason is not None and "ill-conditioned" in one.reason
    assert one.conditioning < 1.2
    # the same wobble on three lanes 3.5 m apart: the lateral spread defines the cross-slope
    three = construct_plane(
        ecef(road_enu(20, lanes=(-3.5, 0.0, 3.5)) + wobble), H, CFG, np.random.default_rng(0)
    )
    assert three.status is PlaneStatus.AVAILABLE
    assert tilt_from_up_deg(three) < 5.0 and three.conditioning > 5.0


def test_single_lane_rarely_gives_a_plane() -> None:
    """Isotropic noise on one lane: the cross-slope is noise. >= 90% unavailable over 100 seeds and
    any plane that does pass is within max_tilt_deg of up."""
    unavailable = 0
    for seed in range(100):
        rng = np.random.default_rng(seed)
        p = construct_plane(ecef(road_enu(20, lanes=(0.0,), noise=0.5, rng=rng)), H, CFG, rng)
        if p.available:
            assert tilt_from_up_deg(p) <= 20.5
        else:
            unavailable += 1
    assert unavailable >= 90


# -- determinism, serialisation, builder -----------------------------------------------------


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), k=st.integers(0, 7))
def test_same_seed_same_plane(seed: int, k: int) -> None:
    pts, _ = with_outliers(k, np.random.default_rng(seed))
    a = construct_plane(pts, H, CFG, np.random.default_rng(seed))
    b = construct_plane(pts, H, CFG, np.random.default_rng(seed))
    assert a.to_dict() == b.to_dict()


def test_to_dict_is_strict_json() -> None:
    rng = np.random.default_rng(3)
    pts, _ = with_outliers(3, rng)
    for p in (
        construct_plane(pts, H, CFG, rng),
        construct_plane(ecef(road_enu(20, lanes=(0.0,))), H, CFG, rng),  # degenerate: NaNs
        construct_plane(ecef(road_enu(20)), H, CFG, rng),  # exact plane: conditioning inf
    ):
        d = json.loads(json.dumps(p.to_dict(), allow_nan=False))
        assert d["status"] == p.status.value
        assert len(d["points_used"]) == p.n_points_used
        assert len(d["points_excluded"]) == p.excluded


def test_plane_arrays_are_read_only() -> None:
    p = construct_plane(ecef(road_enu(20)), H, CFG, np.random.default_rng(0))
    with pytest.raises(ValueError):
        p.normal[0] = 1.0
    with pytest.raises(ValueError):
        p.points_used[0, 0] = 1.0


def test_invalid_input_rejected() -> None:
    pts = ecef(road_enu(20))
    pts[3, 1] = math.nan
    with pytest.raises(ValueError):
        construct_plane(pts, H, CFG, np.random.default_rng(0))
    with pytest.raises(ValueError):
        construct_plane(ecef(road_enu(20)), -1.0, CFG, np.random.default_rng(0))


def test_config_validation() -> None:
    with pytest.raises(ValueError, match="n_max"):
        PlaneConfig(n_max=10, n_min=15)
    with pytest.raises(ValueError, match="t_f_m"):
        PlaneConfig(t_f_m=0.0)
    with pytest.raises(ValueError, match="n_min"):
        PlaneConfig(n_min=2)
    assert (CFG.range_fitting_m, CFG.n_max, CFG.n_min, CFG.t_f_m, CFG.ransac_iterations) == (
        50.0,
        20,
        15,
        5.0,
        7,
    )
    assert CFG.fault_exclusion is True


def build(
    hist: PositionHistory,
    spp: np.ndarray,
    t: float,
    rng: np.random.Generator,
    vehicle_ids: set[str] | None = None,
) -> RoadPlane:
    """The vehicle step's plane: history query around the SPP fix (eq. 3), then construction."""
    return construct_plane(hist.select(spp, t, rng, vehicle_ids=vehicle_ids), H, CFG, rng)


def test_builder_fits_the_fleets_road_from_earlier_epochs() -> None:
    """Four vehicles on a two-lane road at 10 m/s: the plane at t=10 uses epochs 0..9 only."""
    hist = PositionHistory(CFG)
    for t in range(12):
        for i, (lane, start) in enumerate([(-1.75, -40.0), (1.75, -30.0), (-1.75, -20.0), (1.75, -45.0)]):
            enu = np.array([lane, start + 8.0 * t, 0.02 * (start + 8.0 * t) + H])  # antenna 1.6 m up
            hist.add(f"u{i + 1}", float(t), ecef(enu), H)
    spp = ecef(np.array([0.0, 30.0, 0.02 * 30.0 + H + 3.0]))  # an SPP fix 3 m too high
    a = build(hist, spp, 10.0, np.random.default_rng(9))
    assert a.status is PlaneStatus.AVAILABLE, a.reason
    assert a.n_points_initial == CFG.n_max
    assert a.tilt_deg == pytest.approx(math.degrees(math.atan(0.02)), abs=0.05)
    truth_antenna = ecef(np.array([0.0, 30.0, 0.02 * 30.0 + H]))
    assert a.constraint_error(truth_antenna) == pytest.approx(0.0, abs=0.01)
    assert a.constraint_error(spp) == pytest.approx(3.0, abs=0.02)  # the factor sees the 3 m
    only = build(hist, spp, 10.0, np.random.default_rng(9), vehicle_ids={"u1"})
    assert only.status is PlaneStatus.UNAVAILABLE  # one vehicle: a line of too few points
