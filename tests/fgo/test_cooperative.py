"""Cooperative exclusion (coplane.fgo.cooperative): one satellite's FDE residuals added over the
vehicles near one another; the sign convention of the FDE's residuals it relies on."""

from __future__ import annotations

import numpy as np

from coplane.estimation.validate import ValidPseudoranges
from coplane.fgo.cooperative import MIN_KEEP, cooperative_exclusion
from coplane.fgo.prepare import Prepared
from coplane.fgo.screen import screen_pseudoranges
from coplane.fgo.state import StepStats
from coplane.geo import enu_rotation, geodetic_to_ecef

RX = geodetic_to_ecef(np.radians(22.3), np.radians(114.17), 10.0)


def _prs(sats: list[str]) -> ValidPseudoranges:
    n = len(sats)
    return ValidPseudoranges(
        sats,
        [s[0] for s in sats],
        RX + 2.2e7 * np.eye(3)[np.arange(n) % 3],
        np.full(n, 2.2e7),
        np.zeros(n),
        np.full(n, 3.0),
        np.full(n, 0.5),
        np.full(n, 45.0),
    )


def _prep(vid: str, offset_m: float, w: dict[str, float], sats: list[str] | None = None) -> Prepared:
    sats = sats or [f"G{i:02d}" for i in range(1, 9)]
    fde_w = np.array([w.get(s, 0.0) for s in sats])
    return Prepared(
        vid, _prs(sats), sorted({s[0] for s in sats}), None, None, None,
        RX + np.array([offset_m, 0.0, 0.0]), None, {}, {}, len(sats) - 1, fde_w,
    )  # fmt: skip


def test_a_satellite_long_at_every_nearby_vehicle_is_excluded_at_each() -> None:
    preps = {
        "a": _prep("a", 0.0, {"G05": 2.5, "G06": 2.5}),
        "b": _prep("b", 10.0, {"G05": 2.4}),
        "c": _prep("c", 20.0, {"G05": 2.6}),
        "far": _prep("far", 1000.0, {"G05": 2.5}),  # alone out there: its own FDE's call
    }
    stats = StepStats()
    cooperative_exclusion(preps, 3.29, 50.0, stats)
    for vid in ("a", "b", "c"):
        assert "G05" not in preps[vid].prs.sats and len(preps[vid].prs) == 7
        assert preps[vid].rank_self == 6 and preps[vid].fde_w is not None and len(preps[vid].fde_w) == 7
    assert "G06" in preps["a"].prs.sats  # long at one vehicle only: 2.5 / sqrt(3)
    assert len(preps["far"].prs) == 8
    assert stats.rejected["coop_pseudorange"] == 3


def test_never_below_the_minimum_nor_the_last_of_a_system() -> None:
    few = ["G01", "G02", "G03", "G04", "G05", "C01"]
    assert len(few) == MIN_KEEP + 1
    w = {"G05": 4.0, "G04": 3.9, "C01": 5.0}
    preps = {"a": _prep("a", 0.0, w, few), "b": _prep("b", 5.0, w, few)}
    cooperative_exclusion(preps, 3.29, 50.0, StepStats())
    for p in preps.values():
        assert p.prs.sats == ["G01", "G02", "G03", "G04", "C01"]  # the worst GPS one only


def test_vehicles_without_fde_residuals_are_left_alone() -> None:
    a, b = _prep("a", 0.0, {"G05": 9.0}), _prep("b", 5.0, {"G05": 9.0})
    preps = {"a": a, "b": Prepared(**{**b.__dict__, "fde_w": None})}
    cooperative_exclusion(preps, 3.29, 50.0, StepStats())
    assert len(preps["a"].prs) == 8 and len(preps["b"].prs) == 8


def test_fde_residuals_are_positive_for_a_range_measured_too_long() -> None:
    """NLOS lengthens a range: the cooperative test is one-sided on that sign."""
    rng = np.random.default_rng(4)
    n = 10
    az = np.linspace(0.0, 2 * np.pi, n, endpoint=False) + 0.3
    el = np.radians(np.linspace(20.0, 80.0, n))
    los = np.stack([np.cos(el) * np.sin(az), np.cos(el) * np.cos(az), np.sin(el)], axis=1)
    sats = RX + 2.2e7 * (los @ enu_rotation(np.radians(22.3), np.radians(114.17)))
    rho = np.linalg.norm(sats - RX, axis=1) + rng.normal(0.0, 1.0, n)
    rho[3] += 2.5
    prs = ValidPseudoranges(
        [f"G{i:02d}" for i in range(n)], ["G"] * n, sats, rho, np.zeros(n), np.ones(n), el, np.full(n, 45.0)
    )
    res = screen_pseudoranges(prs, RX, np.eye(3), 3.29)
    assert res.w_signed is not None and res.keep.all()
    assert res.w_signed[3] > 1.0 and res.w_signed[3] == np.nanmax(res.w_signed)
