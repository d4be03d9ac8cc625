"""Simulator variants the road-map benchmarks need: a later start (same roads, another sky) and a
re-surfaced road section (RoadRaise)."""

from __future__ import annotations

import numpy as np
import pytest

from coplane.sim.generate import run_simulation
from coplane.sim.road import RaisedProfile, RoadRaise, VerticalProfile


def test_start_offset_moves_the_clock_not_the_road() -> None:
    a = run_simulation("urban-loop", 2, 5.0, seed=7)
    b = run_simulation("urban-loop", 2, 5.0, seed=7, start_offset_s=1800.0)
    assert b.times[0] - a.times[0] == pytest.approx(1800.0)
    # same seed, same drive: the vehicles are where they were, under other satellites
    np.testing.assert_allclose(a.track.ecef, b.track.ecef, atol=1e-9)
    sats_a = {s.sat for s in a.vehicle_obs["u1"][0].sats}
    sats_b = {s.sat for s in b.vehicle_obs["u1"][0].sats}
    pr_a = {s.sat: s.pseudorange_m for s in a.vehicle_obs["u1"][0].sats}
    pr_b = {s.sat: s.pseudorange_m for s in b.vehicle_obs["u1"][0].sats}
    common = sats_a & sats_b
    assert any(abs(pr_a[s] - pr_b[s]) > 1e3 for s in common) or sats_a != sats_b


def test_road_raise_lifts_the_section_smoothly() -> None:
    base = VerticalProfile(1000.0, ())
    r = RoadRaise(s_start_m=400.0, s_end_m=700.0, dz_m=0.5, ramp_m=20.0)
    prof = RaisedProfile(base, (r,))
    s = np.array([100.0, 399.0, 410.0, 420.0, 550.0, 680.0, 700.0, 900.0])
    z = prof.z(s)
    np.testing.assert_allclose(z[[0, 1, 6, 7]], 0.0, atol=1e-12)
    np.testing.assert_allclose(z[[3, 4, 5]], 0.5, atol=1e-12)
    assert z[2] == pytest.approx(0.25)  # half way up the cosine ramp
    # the grade is z's derivative (the motion model drives on it)
    ss = np.linspace(390.0, 710.0, 641)
    num = np.gradient(prof.z(ss), ss)
    np.testing.assert_allclose(prof.grade(ss)[1:-1], num[1:-1], atol=2e-3)
    with pytest.raises(ValueError, match="both ramps"):
        RoadRaise(s_start_m=0.0, s_end_m=30.0, dz_m=0.5, ramp_m=20.0)


def test_raised_run_differs_only_in_height_there() -> None:
    plain = run_simulation("urban-loop", 1, 60.0, seed=3)
    raised = run_simulation("urban-loop", 1, 60.0, seed=3, road_raise=(RoadRaise(0.0, 10000.0, 0.5),))
    d_up = [
        float((q - p) @ (p / np.linalg.norm(p)))
        for p, q in zip(plain.track.ecef[:, 0], raised.track.ecef[:, 0], strict=True)
    ]
    assert np.median(d_up) == pytest.approx(0.5, abs=0.05)
