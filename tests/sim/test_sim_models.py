"""Unit tests of the simulator's models: road, vertical profile, motion, canyon, clocks, errors, UWB."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from coplane.sim.canyon import BLOCKED, LOS, NLOS, Canyon
from coplane.sim.errors import (
    ClockParams,
    Cn0Params,
    GaussMarkov,
    ReceiverClocks,
    TrackingParams,
    code_sigma_m,
    component_rng,
    doppler_sigma_hz,
)
from coplane.sim.motion import simulate_motion
from coplane.sim.road import GradeChange, Road, Sections, VerticalProfile
from coplane.sim.scenarios import SCENARIOS, get_scenario
from coplane.sim.uwb import UwbParams, UwbSimulator


def _road(name: str = "urban-loop") -> tuple[Road, Sections]:
    rp = get_scenario(name).road
    road = Road(rp.waypoints_en, rp.corner_radius_m, rp.lanes, rp.lane_width_m, rp.grade_changes)
    return road, Sections(road.length_m, rp.sections)


def _plane_residual(points: np.ndarray) -> float:
    """Largest distance of points from their least-squares plane (SVD, as a plane fit does)."""
    c = points - points.mean(axis=0)
    normal = np.linalg.svd(c)[2][2]
    return float(np.abs(c @ normal).max())


# --- road -------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", sorted(SCENARIOS))
def test_profile_closes_and_grades_are_3_to_5_percent(name: str) -> None:
    road, _ = _road(name)
    prof = road.profile
    assert abs(prof.closure_error_m) < 1e-6
    s = np.arange(0.0, road.length_m, 0.5)
    g = prof.grade(s)
    tangent = prof.curvature(s) == 0.0
    sloped = np.abs(g[tangent]) > 1e-9
    assert sloped.any()
    # every constant grade that is not flat is a 3-5 % grade (the range)
    assert np.all((np.abs(g[tangent][sloped]) >= 0.03 - 1e-12) & (np.abs(g[tangent][sloped]) <= 0.05 + 1e-12))
    assert (g > 0.029).any() and (g < -0.029).any()  # climbs and descents
    # z and grade are continuous (no steps): increments bounded by max grade * step
    assert np.abs(np.diff(prof.z(s))).max() <= 0.05 * 0.5 + 1e-9
    assert np.abs(np.diff(g)).max() < 0.01


def test_vertical_curve_is_not_planar_but_grades_are() -> None:
    """Over 60 m of two lanes, a crest curve leaves > 0.1 m off the best plane; a grade 0 mm."""
    road, _ = _road()
    crest = next(c for c in road.profile.vertical_curves() if c[2] > 0 > c[3])  # + grade to - grade
    mid = (crest[0] + crest[1]) / 2
    s = np.linspace(mid - 30.0, mid + 30.0, 61)
    pts = np.concatenate([road.antenna_enu(s, np.full_like(s, y), 0.0) for y in (-1.75, 1.75)])
    assert _plane_residual(pts) > 0.1
    curves = road.profile.vertical_curves()
    grade_s = next(
        (a[1] + b[0]) / 2
        for a, b in itertools.pairwise(curves)
        if abs(a[3]) >= 0.03 and b[0] - a[1] > 80  # a long constant-grade tangent
    )
    s2 = np.linspace(grade_s - 30.0, grade_s + 30.0, 61)
    pts2 = np.concatenate([road.antenna_enu(s2, np.full_like(s2, y), 0.0) for y in (-1.75, 1.75)])
    assert _plane_residual(pts2) < 1e-3


def test_road_has_left_and_right_turns_and_continuous_centreline() -> None:
    road, _ = _road()
    turns = road.turns()
    assert len(turns) >= 4
    assert {t[2] for t in turns} == {1.0, -1.0}
    s = np.arange(0.0, road.length_m + 1.0, 0.25)
    p, t, _ = road.frame(s)
    step = np.linalg.norm(np.diff(p, axis=0), axis=1)
    assert step.max() < 0.2501 and step.min() > 0.24  # arc length parametrisation, closed loop
    assert np.linalg.norm(p[0] - road.frame(np.array([road.length_m]))[0][0]) < 1e-6
    assert np.allclose(np.linalg.norm(t, axis=1), 1.0)


def test_vertical_profile_rejects_overlapping_curves() -> None:
    with pytest.raises(ValueError, match="overlaps"):
        VerticalProfile(1000.0, (GradeChange(100.0, 0.04, 100.0), GradeChange(120.0, 0.0, 100.0)))


def test_antenna_sits_along_the_surface_normal() -> None:
    road, _ = _road()
    s = np.array([500.0])  # +4 % grade
    base = road.antenna_enu(s, np.zeros(1), 0.0)[0]
    ant = road.antenna_enu(s, np.zeros(1), 2.0)[0]
    d = ant - base
    assert np.linalg.norm(d) == pytest.approx(2.0, abs=1e-9)
    _, t, _ = road.frame(s)
    along = d[:2] @ t[0]
    assert along == pytest.approx(-2.0 * 0.04 / math.sqrt(1 + 0.04**2), abs=1e-9)  # leans back uphill


# --- motion -----------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def fleet16() -> tuple[Road, Sections, object]:
    road, secs = _road()
    sc = get_scenario("urban-loop")
    rp = sc.road
    track = simulate_motion(
        road,
        secs,
        sc.motion,
        16,
        400,
        1.0,
        (rp.origin_lat_deg, rp.origin_lon_deg, rp.origin_h_m),
        component_rng(5, "motion"),
    )
    return road, secs, track


def test_speeds_heights_lanes_and_gaps(fleet16: tuple) -> None:
    road, _, tr = fleet16
    assert tr.speed.min() >= 5.0 and tr.speed.max() <= 15.0
    assert tr.antenna_height_m.min() >= 1.4 and tr.antenna_height_m.max() <= 2.1
    assert len(np.unique(tr.lane)) == 2
    assert np.abs(tr.y).max() <= 1.75 + 1e-9
    # bumper-to-bumper gaps in a lane stay positive and vary (car following, not a fixed formation)
    L = road.length_m
    min_gap, gaps = np.inf, []
    for k in range(tr.s.shape[0]):
        for lane in (0, 1):
            settled = (tr.lane[k] == lane) & (np.abs(tr.y[k] - road.lane_offset(lane)) < 0.05)
            s = np.sort(tr.s[k][settled])
            if len(s) > 1:
                d = np.diff(np.append(s, s[0] + L)) - 4.5
                min_gap = min(min_gap, float(d.min()))
                gaps.extend(d[d < 200].tolist())
    print(f"16 vehicles x 400 s: min bumper gap {min_gap:.1f} m, gap spread {np.std(gaps):.1f} m")
    assert min_gap > 2.0
    assert np.std(gaps) > 3.0


def test_truth_velocity_is_the_derivative_of_truth_position(fleet16: tuple) -> None:
    _, _, tr = fleet16
    fd = (tr.ecef[2:] - tr.ecef[:-2]) / 2.0  # central difference over +-1 s
    err = np.linalg.norm(fd - tr.vel_ecef[1:-1], axis=-1)
    assert np.median(err) < 0.05  # m/s; larger only where the car accelerates or turns


# --- canyon -----------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def canyon() -> Canyon:
    road, secs = _road()
    return Canyon(road, secs, get_scenario("urban-loop").canyon, component_rng(0, "canyon"))


def _sky(n_az: int = 72, els: tuple[float, ...] = (10, 20, 30, 45, 60, 75)) -> tuple[np.ndarray, np.ndarray]:
    az, el = np.meshgrid(np.radians(np.arange(n_az) * 360 / n_az), np.radians(els))
    return az.ravel()[None, :], el.ravel()[None, :]


def test_canyon_blocks_more_in_deep_sections_and_nothing_in_open(canyon: Canyon) -> None:
    road, secs = canyon.road, canyon.sections
    az, el = _sky()
    frac = {}
    for kind in ("open", "medium", "deep"):
        ss = [
            s for sec in secs.sections if sec.kind == kind for s in np.arange(sec.s0 + 15, sec.s1 - 15, 7.0)
        ]
        ss = [s for s in ss if road.frame(np.array([s]))[2][0] == 0.0]
        s = np.array(ss)
        _, hd, _ = road.frame(s)
        vis = canyon.visibility(
            s,
            np.full_like(s, -1.75),
            np.full_like(s, 1.7),
            hd,
            np.repeat(az, len(s), 0),
            np.repeat(el, len(s), 0),
        )
        frac[kind] = {st: float(np.mean(vis.state == st)) for st in (LOS, NLOS, BLOCKED)}
        assert np.all(vis.excess_m[vis.state == NLOS] > 0.0)  # NLOS: only positive extra path
        assert np.all(vis.excess_m[vis.state != NLOS] == 0.0)
    print(
        "share of sky (LOS, NLOS, blocked):",
        {k: tuple(round(v, 2) for v in f.values()) for k, f in frac.items()},
    )
    assert frac["open"][LOS] > 0.97
    assert frac["deep"][LOS] < frac["medium"][LOS] < frac["open"][LOS]
    assert frac["deep"][NLOS] > 0.05


def test_underpass_blocks_everything_under_the_deck(canyon: Canyon) -> None:
    (d0, d1) = canyon.decks[0]
    s = np.linspace(d0 + 0.5, d1 - 0.5, 20)
    _, hd, _ = canyon.road.frame(s)
    az, el = _sky(els=(5, 30, 60, 89))
    vis = canyon.visibility(
        s, np.zeros_like(s), np.full_like(s, 2.0), hd, np.repeat(az, 20, 0), np.repeat(el, 20, 0)
    )
    assert np.all(vis.state == BLOCKED)


def test_nlos_extra_path_is_the_image_method_value() -> None:
    """A ray toward the left facade reflected off the right one: 2 d cos(el) |sin a|."""
    d, el, a = 12.0, math.radians(30.0), math.radians(70.0)
    extra = Canyon.reflection_extra(
        np.array(10.0),
        np.array(1.0),
        np.array(2.0),
        np.array([1.0, 0.0]),
        np.array(math.pi / 2 - a),
        np.array(el),
    )
    assert float(extra) == pytest.approx(2 * d * math.cos(el) * math.sin(a), rel=1e-12)


# --- clocks and noise -------------------------------------------------------------------------


def test_clock_jumps_are_whole_milliseconds_and_tags_are_a_few_ms_off() -> None:
    p = ClockParams(drift_ppm=(2.0, 2.5))  # 1 ms of drift in 400-500 s: jumps within 20 min
    clocks = ReceiverClocks([p] * 20, 1200, 1.0, component_rng(1, "clock"))
    jumps = clocks.jumps[clocks.jumps != 0.0]
    assert len(jumps) >= 20
    assert np.allclose(np.abs(jumps), 1e-3, rtol=0, atol=1e-15)
    # between epochs the bias moves by drift (+ tiny noise) plus the jump, nothing else
    step = np.diff(clocks.bias, axis=0) - clocks.drift[:-1] * 1.0 - clocks.jumps[1:]
    assert np.abs(step).max() < 1e-8
    assert np.abs(clocks.bias).max() < 6.0e-3  # tags stay within a few ms of the whole second
    steered = ReceiverClocks([ClockParams(steered=True)], 100, 1.0, component_rng(1, "clock"))
    assert np.abs(steered.bias).max() < 1e-7 and not steered.jumps.any()


def test_code_and_doppler_noise_follow_cn0() -> None:
    tp = TrackingParams()
    s45, s30 = code_sigma_m(np.array([45.0, 30.0]), np.array([False, False]), tp)
    assert 0.3 < s45 < 0.7 and 2.0 < s30 < 4.0  # Kaplan & Hegarty DLL jitter, d = 0.2 chip
    b45 = code_sigma_m(np.array([45.0]), np.array([True]), tp)[0]
    assert b45 == pytest.approx(s45 / 2, rel=1e-9)  # B1I chip is half as long
    d45, d25 = doppler_sigma_hz(np.array([45.0, 25.0]), tp)
    assert d45 == pytest.approx(0.05) and d25 == pytest.approx(0.5)
    assert Cn0Params().track_threshold_dbhz > 20


def test_gauss_markov_is_stationary_with_the_right_sigma_and_correlation() -> None:
    gm = GaussMarkov((2000,), tau_s=10.0, dt_s=1.0, rng=component_rng(0, "t"))
    xs = np.array([gm.step().copy() for _ in range(200)])
    assert np.std(xs) == pytest.approx(1.0, abs=0.03)
    lag1 = np.mean(xs[1:] * xs[:-1]) / np.mean(xs * xs)
    assert lag1 == pytest.approx(math.exp(-0.1), abs=0.02)


def test_component_streams_are_stable_and_independent() -> None:
    a = component_rng(7, "iono").standard_normal(3)
    b = component_rng(7, "iono").standard_normal(3)
    c = component_rng(7, "tropo").standard_normal(3)
    assert np.array_equal(a, b) and not np.array_equal(a, c)


# --- UWB --------------------------------------------------------------------------------------


def test_uwb_none_beyond_500_m_noise_and_positive_nlos_bias() -> None:
    n = 12
    pos = np.zeros((n, 3))
    pos[:, 0] = np.arange(n) * 60.0  # a straight line, 60 m apart: up to 660 m, middle cars block
    pos[:, 2] = 6.37e6
    sim = UwbSimulator(n, UwbParams(max_neighbours=n), None, component_rng(0, "uwb"))
    los_err, nlos_err, n_rows = [], [], 0
    for _ in range(300):
        ep = sim.step(pos, pos[:, :2])
        n_rows += len(ep.i)
        assert np.all(ep.true_m <= 500.0)
        err = ep.range_m - ep.true_m
        los_err.extend(err[ep.nlos == 0])
        nlos_err.extend(err[ep.nlos == 1])
    assert n_rows > 0
    print(f"UWB: LOS error std {np.std(los_err):.3f} m, NLOS mean bias {np.mean(nlos_err):.2f} m")
    assert np.std(los_err) == pytest.approx(0.3, abs=0.03)
    assert abs(np.mean(los_err)) < 0.05
    assert np.mean(nlos_err) > 0.5


def test_uwb_dropouts_come_in_bursts() -> None:
    pos = np.array([[0.0, 0.0, 6.37e6], [20.0, 0.0, 6.37e6]])
    sim = UwbSimulator(2, UwbParams(), None, component_rng(3, "uwb"))
    got = np.array([len(sim.step(pos, pos[:, :2]).i) > 0 for _ in range(5000)])
    lost = ~got
    p_loss = lost.mean()
    p_loss_after_loss = (lost[1:] & lost[:-1]).sum() / lost[:-1].sum()
    print(f"UWB loss rate {p_loss:.3f}, P(loss | previous lost) {p_loss_after_loss:.2f}")
    assert 0.03 < p_loss < 0.3
    assert p_loss_after_loss > 3 * p_loss  # Gilbert-Elliott bursts, not independent losses
