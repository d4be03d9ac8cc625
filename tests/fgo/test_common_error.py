"""The reported covariance's term for the errors the window cannot average (`fgo.common_error`):
its model per satellite, the columns that carry it to the estimator, the snapshot covariance it
makes, and that it changes what is reported and nothing that is estimated."""

from __future__ import annotations

import dataclasses
import math
from collections import Counter

import numpy as np
import pytest

from coplane.estimation.contract import EpochInput, PseudorangeColumns
from coplane.estimation.validate import ValidPseudoranges, _valid_pseudoranges
from coplane.fgo.common_error import common_error_covariance
from coplane.gnss.weighting import BROADCAST_IONO_ERROR_FRACTION, SAAS_RESIDUAL_M, common_error_sigma_m
from coplane.messages import NodeMessage
from coplane.methods import get_method
from coplane.steps.wire import pseudorange_columns
from tests.fgo.test_screen import RX, _epoch
from tests.steps.test_pseudorange_columns import columns
from tests.support.fgo_synthetic import make_fleet, run
from tests.support.wire_payloads import node, sat, satellites


def test_the_model_per_satellite() -> None:
    el = np.radians([90.0, 30.0, 2.0])
    iono = np.array([4.0, 8.0, 10.0])
    assert common_error_sigma_m(el, iono, [True, True, True]).tolist() == [0.0, 0.0, 0.0]  # DGNSS
    sa = common_error_sigma_m(el, iono, [False, False, False])
    expect = math.hypot(BROADCAST_IONO_ERROR_FRACTION * 8.0, SAAS_RESIDUAL_M / (0.5 + 0.1))
    assert sa[1] == pytest.approx(expect)
    low = math.hypot(
        BROADCAST_IONO_ERROR_FRACTION * 10.0, SAAS_RESIDUAL_M / (math.sin(math.radians(5.0)) + 0.1)
    )
    assert sa[2] == pytest.approx(low)  # clamped at 5 degrees
    assert np.all(sa > 0) and sa[0] < sa[1] < sa[2]


def test_the_wire_builds_it_from_each_satellite_s_mode() -> None:
    """A satellite without a DGNSS correction gets the broadcast atmosphere's residual (from its
    own iono delay and elevation); one with a correction has none."""
    msg = NodeMessage.model_validate(
        node(satellites=satellites(sat(), sat(sat="G07", dgnss_m=3.0, iono_m=0.0)))
    )
    c = pseudorange_columns(msg)
    assert c.common_sigma_m is not None
    el = math.radians(35.0)
    assert c.common_sigma_m.tolist() == pytest.approx([common_error_sigma_m([el], [3.4], [False])[0], 0.0])


def test_an_unusable_common_sigma_is_unknown_and_keeps_its_row() -> None:
    """Not a measurement: a bad value loses the report's term, never the pseudorange."""
    fleet = make_fleet(1, 1, seed=3)
    good = columns(fleet.epochs[0].vehicles["v01"].pseudoranges)  # type: ignore[arg-type]
    n = len(good)
    common = np.full(n, 2.0)
    common[0], common[1], common[2] = -1.0, math.inf, 1e9
    rejected: Counter[str] = Counter()
    valid = _valid_pseudoranges(dataclasses.replace(good, common_sigma_m=common), rejected)
    assert len(valid) == n and not rejected
    assert valid.common_sigma is not None
    assert np.isnan(valid.common_sigma[:3]).all() and np.all(valid.common_sigma[3:] == 2.0)
    assert valid.subset([3, 4]).common_sigma.tolist() == [2.0, 2.0]  # type: ignore[union-attr]
    assert _valid_pseudoranges(good, rejected).common_sigma is None  # no column: unknown


def test_the_snapshot_covariance() -> None:
    """Equal sigmas s: s^2 (H^T H)^-1's position block; the height takes the most; rows with
    an unknown sigma, or too few rows, make no claim."""
    prs = _epoch(8, 1.0, np.random.default_rng(1))
    none = common_error_covariance(prs, RX)
    assert none is None  # the column is absent
    prs = dataclasses.replace(prs, common_sigma=np.full(len(prs), 2.0))
    cov = common_error_covariance(prs, RX)
    assert cov is not None
    los = prs.sat_pos - RX
    h = np.column_stack([-los / np.linalg.norm(los, axis=1)[:, None], np.ones(len(prs))])
    assert cov == pytest.approx(4.0 * np.linalg.inv(h.T @ h)[:3, :3], rel=1e-9)
    up = RX / np.linalg.norm(RX)
    assert up @ cov @ up > 0.5 * np.trace(cov)  # satellites above only: the height is weakest
    assert common_error_covariance(prs.subset(list(range(4))), RX) is None  # 4 rows, 4 unknowns
    for bad in (math.nan, 0.0):  # unknown, or no common error (DGNSS): no claim about the epoch
        sig = prs.common_sigma.copy()  # type: ignore[union-attr]
        sig[0] = bad
        assert common_error_covariance(dataclasses.replace(prs, common_sigma=sig), RX) is None


def _with_common(epoch: EpochInput, sigma: float) -> EpochInput:
    """The epoch's pseudoranges as columns with this common sigma, and 45 degrees of elevation
    where the synthetic fleet gives none (the DGNSS model needs one)."""
    vehicles = {}
    for v, vin in epoch.vehicles.items():
        c: PseudorangeColumns = columns(vin.pseudoranges)  # type: ignore[arg-type]
        el = np.where(np.isnan(c.elevation_rad), math.radians(45.0), c.elevation_rad)
        prs = dataclasses.replace(c, common_sigma_m=np.full(len(c), sigma), elevation_rad=el)
        vehicles[v] = dataclasses.replace(vin, pseudoranges=prs)
    return dataclasses.replace(epoch, vehicles=vehicles)


def test_it_changes_the_reported_covariance_and_nothing_estimated() -> None:
    fleet = make_fleet(3, 10, seed=8)
    epochs = [_with_common(e, 1.5) for e in fleet.epochs]
    base = dataclasses.replace(get_method("pc").fgo, covariance_scale=1.0)
    off = run(fleet, base, epochs)
    on = run(fleet, dataclasses.replace(base, covariance_common_scale=2.0), epochs)
    grew = 0
    for a, b in zip(off, on, strict=True):
        assert sorted(a.estimates) == sorted(b.estimates)
        for v in a.estimates:
            ea, eb = a.estimates[v], b.estimates[v]
            assert np.array_equal(ea.position_m, eb.position_m)
            added = np.asarray(eb.covariance_m2) - np.asarray(ea.covariance_m2)
            assert np.all(np.linalg.eigvalsh(0.5 * (added + added.T)) > -1e-9)  # only ever more
            grew += bool(np.trace(added) > 1.0)  # 2^2 x a 1.5 m snapshot: metres squared
    assert grew >= 20


def test_valid_pseudoranges_keep_it_optional() -> None:
    """Positional construction without the column still works (tests and older callers)."""
    prs = ValidPseudoranges(
        ["G01"], ["G"], np.ones((1, 3)), np.ones(1), np.zeros(1), np.ones(1), np.ones(1), np.ones(1)
    )
    assert prs.common_sigma is None and prs.subset([0]).common_sigma is None


def test_dgnss_rows_add_nothing_unless_the_base_is_modelled() -> None:
    """A DGNSS epoch (common sigma 0: the atmosphere cancelled) reports exactly what it reported
    without the term; `covariance_common_dgnss_m` models the base station's errors instead."""
    fleet = make_fleet(2, 6, seed=4)
    epochs = [_with_common(e, 0.0) for e in fleet.epochs]
    base = get_method("pc").fgo
    off = run(fleet, base, epochs)
    on = run(fleet, dataclasses.replace(base, covariance_common_scale=1.0), epochs)
    modelled = run(
        fleet, dataclasses.replace(base, covariance_common_scale=1.0, covariance_common_dgnss_m=0.75), epochs
    )
    for a, b, c in zip(off, on, modelled, strict=True):
        for v in a.estimates:
            assert np.array_equal(a.estimates[v].covariance_m2, b.estimates[v].covariance_m2)
            assert np.array_equal(a.estimates[v].position_m, c.estimates[v].position_m)
    last = off[-1].estimates["v01"].covariance_m2, modelled[-1].estimates["v01"].covariance_m2
    assert np.trace(last[1] - last[0]) > 0.5  # 0.75 m at the zenith, more below
    prs = dataclasses.replace(_epoch(8, 1.0, np.random.default_rng(2)), common_sigma=np.zeros(8))
    assert common_error_covariance(prs, RX) is None
    cov = common_error_covariance(prs, RX, dgnss_zenith_m=0.75)
    ref = common_error_covariance(dataclasses.replace(prs, common_sigma=0.75 / np.sin(prs.elevation)), RX)
    assert cov is not None and ref is not None and np.allclose(cov, ref)


@pytest.mark.parametrize("name", ["covariance_common_scale", "covariance_common_dgnss_m"])
@pytest.mark.parametrize("bad", [-0.1, math.inf, math.nan])
def test_a_bad_setting_is_refused_naming_it(name: str, bad: float) -> None:
    with pytest.raises(ValueError, match=name):
        dataclasses.replace(get_method("pc").fgo, **{name: bad})  # type: ignore[arg-type]
