"""The estimator's column form of the pseudoranges (what the fusion server builds from a node
message) is validated and solved exactly like the form with one object per satellite, and bad
columns are counted, never raised."""

from __future__ import annotations

import dataclasses
import math
from collections import Counter
from collections.abc import Sequence

import numpy as np

from coplane.estimation.contract import EpochInput, PseudorangeColumns, PseudorangeObs
from coplane.estimation.validate import _valid_pseudoranges, validate_epoch
from coplane.messages import NodeMessage, SatelliteColumns
from coplane.methods import get_method
from coplane.steps.wire import pseudorange_columns
from tests.support.fgo_synthetic import make_fleet, run
from tests.support.wire_payloads import SAT, node, sat, satellites


def columns(prs: Sequence[PseudorangeObs]) -> PseudorangeColumns:
    return PseudorangeColumns(
        sats=tuple(o.sat for o in prs),
        sat_pos_m=np.array([o.sat_pos_m for o in prs], dtype=float).reshape(-1, 3),
        rho_m=np.array([o.rho_m for o in prs]),
        sat_clock_s=np.array([o.sat_clock_s for o in prs]),
        sigma_m=np.array([o.sigma_m for o in prs]),
        elevation_rad=np.array([o.elevation_rad for o in prs]),
        cn0_dbhz=np.array([o.cn0_dbhz for o in prs]),
    )


def as_columns(epoch: EpochInput) -> EpochInput:
    vehicles = {
        v: dataclasses.replace(vin, pseudoranges=columns(vin.pseudoranges))  # type: ignore[arg-type]
        for v, vin in epoch.vehicles.items()
    }
    return dataclasses.replace(epoch, vehicles=vehicles)


def test_columns_solve_like_objects() -> None:
    """Bit for bit the same estimates from either form (pc, a synthetic fleet)."""
    fleet = make_fleet(3, 12, seed=21)
    cfg = get_method("pc").fgo
    a = run(fleet, cfg)
    b = run(fleet, cfg, [as_columns(e) for e in fleet.epochs])
    for sa, sb in zip(a, b, strict=True):
        assert sorted(sa.estimates) == sorted(sb.estimates)
        for v in sa.estimates:
            assert np.array_equal(sa.estimates[v].position_m, sb.estimates[v].position_m)
            assert np.array_equal(sa.estimates[v].covariance_m2, sb.estimates[v].covariance_m2)


def test_bad_columns_are_counted_not_raised() -> None:
    fleet = make_fleet(1, 1, seed=3)
    prs = fleet.epochs[0].vehicles["v01"].pseudoranges
    good = columns(prs)  # type: ignore[arg-type]
    n = len(good)
    rho = good.rho_m.copy()
    rho[0] = math.nan
    sigma = good.sigma_m.copy()
    sigma[1] = -1.0
    sats = ("X05", *good.sats[1:3], good.sats[2], *good.sats[4:])  # unknown system, duplicate
    bad = dataclasses.replace(good, sats=sats, rho_m=rho, sigma_m=sigma)
    rejected: Counter[str] = Counter()
    valid = _valid_pseudoranges(bad, rejected)
    assert rejected["pseudorange"] == 3  # row 0 (NaN rho, system X), row 1 (sigma), row 3 (a repeat)
    assert valid.sats == list(good.sats[2:3]) + list(good.sats[4:])
    # columns of inconsistent lengths: every row is malformed, nothing raises
    short = dataclasses.replace(good, rho_m=good.rho_m[:-1])
    rejected.clear()
    assert len(_valid_pseudoranges(short, rejected)) == 0 and rejected["pseudorange"] == n
    rejected.clear()
    huge = dataclasses.replace(good, rho_m=[10**400] * n)  # type: ignore[arg-type]
    assert len(_valid_pseudoranges(huge, rejected)) == 0 and rejected["pseudorange"] == n
    rejected.clear()
    junk = dataclasses.replace(good, sats=None, sat_pos_m="junk")  # type: ignore[arg-type]
    assert len(_valid_pseudoranges(junk, rejected)) == 0 and rejected["pseudorange"] == 1


def test_columns_from_a_node_message() -> None:
    """The used satellites in the message's order; elevation in radians; no C/N0 is NaN."""
    rows = satellites(
        sat(),
        sat(sat="E11", used=False),
        sat(sat="C14", elevation_deg=60.0, rho_m=3.8e7, cn0_dbhz=None),
    )
    msg = NodeMessage.model_validate(node(satellites=rows))
    c = pseudorange_columns(msg)
    assert c.sats == ("G05", "C14")
    assert c.sat_pos_m.shape == (2, 3) and np.array_equal(c.sat_pos_m[1], SAT)
    assert np.array_equal(c.rho_m, [2.2e7 - 7.0, 3.8e7])
    assert c.elevation_rad.tolist() == [math.radians(35.0), math.radians(60.0)]
    assert c.cn0_dbhz[0] == 42.0 and math.isnan(c.cn0_dbhz[1])
    empty = pseudorange_columns(msg.model_copy(update={"satellites": SatelliteColumns()}))
    assert len(empty) == 0 and empty.sat_pos_m.shape == (0, 3)


def test_numbers_beyond_a_float_are_counted_not_raised() -> None:
    """An int too large for a float (float() raises OverflowError) wherever a number goes."""
    fleet = make_fleet(2, 1, seed=5)
    epoch = fleet.epochs[0]
    v = epoch.vehicles["v01"]
    huge = 10**400
    prs = (dataclasses.replace(v.pseudoranges[0], rho_m=huge), *v.pseudoranges[1:])  # type: ignore[arg-type]
    bad = dataclasses.replace(
        v, pseudoranges=prs, spp_position=[huge, 0, 0], antenna_height_m=huge, clock_drift_mps=huge
    )
    got = validate_epoch(dataclasses.replace(epoch, vehicles={**epoch.vehicles, "v01": bad}))
    assert got.rejected == {"pseudorange": 1, "spp": 1, "antenna_height": 1, "clock_drift": 1}
    assert len(got.vehicles["v01"].pseudoranges) == len(v.pseudoranges) - 1


def test_a_bad_id_among_good_rows_is_counted() -> None:
    """Validation skips its row loop when every row is plausible and no satellite repeats: an
    unknown system, a repeat or a non-string id among numerically good rows must still take the
    loop, lose that row alone and count it."""
    fleet = make_fleet(1, 1, seed=3)
    good = columns(fleet.epochs[0].vehicles["v01"].pseudoranges)  # type: ignore[arg-type]
    rejected: Counter[str] = Counter()
    valid = _valid_pseudoranges(good, rejected)
    assert not rejected and valid.sats == list(good.sats)
    n = len(good)
    others = list(range(1, n))
    cases = (
        ("X05", "unknown system", others),
        (good.sats[1], "a repeat: the first of the two is kept", [0, *range(2, n)]),
        (5, "not a string", others),
    )
    for first, why, rows in cases:
        bad = dataclasses.replace(good, sats=(first, *good.sats[1:]))
        rejected.clear()
        valid = _valid_pseudoranges(bad, rejected)
        assert rejected["pseudorange"] == 1, why
        assert valid.sats == [bad.sats[i] for i in rows], why
        assert np.array_equal(valid.rho, good.rho_m[rows]), why
