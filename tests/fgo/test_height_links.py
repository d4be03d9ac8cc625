"""Road-height links (`coplane.fgo.height_links`, docs/fgo.md "Road-height links")."""

from __future__ import annotations

import dataclasses
from collections import Counter

import gtsam
import numpy as np
import pytest
from support.fgo_synthetic import error_stats, make_fleet, run

from coplane.estimation.validate import validate_vehicle
from coplane.fgo import factors as F
from coplane.fgo.config import FgoConfig
from coplane.fgo.height_links import _doppler_rise
from coplane.geo import geodetic_to_ecef, up_vector
from coplane.methods import get_method


def test_a_height_link_measures_only_the_height_difference() -> None:
    """Horizontal moves are free; the height difference is measured against the antennas'."""
    a = geodetic_to_ecef(0.6, 2.0, 30.0)
    u = up_vector(a)
    east = np.cross([0.0, 0.0, 1.0], u)
    east /= np.linalg.norm(east)
    b = a + 20.0 * east
    f = F.height_link_factor(1, 2, a, b, 0.3, 0.5)
    values = gtsam.Values()
    values.insert(1, a)

    def err(p: np.ndarray) -> float:
        v = gtsam.Values(values)
        v.insert(2, p)
        return float(f.error(v))

    assert err(b + 0.3 * u) < 1e-9
    assert err(b + 0.3 * u + 15.0 * east) < 1e-3  # 15 m along the road: nothing
    assert abs(err(b + 0.8 * u) - 0.5) < 1e-6  # 0.5 m = one sigma: error 1/2


def test_a_bad_antenna_height_is_counted_and_the_vehicle_kept() -> None:
    fleet = make_fleet(2, 1, seed=0)
    vin = fleet.epochs[0].vehicles["v01"]
    rejected: Counter[str] = Counter()
    got = validate_vehicle("v01", dataclasses.replace(vin, antenna_height_m=11.0), vin.time, rejected)
    assert not isinstance(got, str) and got.antenna_height_m is None
    assert rejected == Counter({"antenna_height": 1})
    ok = validate_vehicle("v01", vin, vin.time, Counter())
    assert not isinstance(ok, str) and ok.antenna_height_m == vin.antenna_height_m


def test_height_links_are_counted_apart_from_ranges_and_only_with_planes() -> None:
    fleet = make_fleet(4, 8, seed=1)
    for name, expect in (("pc", True), ("mci", False)):
        spec = get_method(name)
        assert spec.fgo is not None
        cfg = dataclasses.replace(spec.fgo, height_link_max_m=50.0)
        ref = run(fleet, dataclasses.replace(spec.fgo, height_link_max_m=0.0))  # no links
        sols = run(fleet, cfg)
        last = sols[-1]
        assert ("height_link" in last.factor_counts) is expect, (name, last.factor_counts)
        assert last.factor_counts.get("range") == ref[-1].factor_counts.get("range")
        for vid, est in last.estimates.items():
            assert est.n_ranges == ref[-1].estimates[vid].n_ranges


def test_a_neighbour_carries_a_height_the_satellites_do_not_fix() -> None:
    """v01 keeps 5 satellites (a canyon) and no plane: its height comes from the links.
    Measured: V RMSE 1.06 m with them (Doppler grades; 1.05 m with the fixed grade), 2.68 m
    without (H 0.71, 0.68 and 2.07 m)."""
    limit = {("v01", k): 5 for k in range(30)}
    fleet = make_fleet(4, 30, seed=2, with_planes=False, sat_limit=limit)
    base = get_method("pc").fgo
    assert base is not None
    no_links = dataclasses.replace(base, height_link_max_m=0.0)
    off = error_stats(fleet, run(fleet, no_links), vehicles=["v01"], skip=5)
    on = error_stats(
        fleet, run(fleet, dataclasses.replace(base, height_link_max_m=50.0)), vehicles=["v01"], skip=5
    )
    assert on.v_rmse < 0.5 * off.v_rmse, (on, off)
    assert on.h_rmse < off.h_rmse, (on, off)


def test_the_doppler_grades_predict_the_rise_along_the_heading() -> None:
    """On a 5 % grade, b 20 m ahead of a lies 1 m higher; side by side, level. Two grades that
    disagree predict their mean and widen the sigma by half their difference. No prediction
    when either end lacks a grade (no Doppler, below 2 m/s, or above 15 %: a biased velocity),
    nor when the prediction is off."""
    a = geodetic_to_ecef(0.6, 2.0, 30.0)
    u = up_vector(a)
    east = np.cross([0.0, 0.0, 1.0], u)
    east /= np.linalg.norm(east)
    north = np.cross(u, east)
    cfg = FgoConfig(height_link_max_m=50.0, height_link_doppler_grade_sigma=0.02)
    fleet = make_fleet(2, 1, seed=0)
    vin = validate_vehicle("v01", fleet.epochs[0].vehicles["v01"], fleet.epochs[0].time, Counter())
    assert not isinstance(vin, str)

    def rise(
        b: np.ndarray, va: np.ndarray | None, vb: np.ndarray | None, c: FgoConfig = cfg
    ) -> tuple[float, float] | None:
        ends = [dataclasses.replace(vin, velocity=v, velocity_sigma=0.05) for v in (va, vb)]
        return _doppler_rise(a, b, ends[0], ends[1], c)

    up_hill, level = 10.0 * east + 0.5 * u, 10.0 * east
    assert rise(a + 20.0 * east, up_hill, up_hill) == pytest.approx((1.0, 0.02))
    assert rise(a + 20.0 * north, up_hill, up_hill) == pytest.approx((0.0, 0.02), abs=1e-9)
    assert rise(a + 20.0 * east, up_hill, level) == pytest.approx((0.5, float(np.hypot(0.02, 0.025))))
    for no_grade in (None, 1.0 * east, 10.0 * east + 2.0 * u):
        assert rise(a + 20.0 * east, up_hill, no_grade) is None
    off = dataclasses.replace(cfg, height_link_doppler_grade_sigma=0.0)
    assert rise(a + 20.0 * east, up_hill, up_hill, off) is None
