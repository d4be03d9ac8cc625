"""Direct tests of the wire models' validators (`coplane.messages`).

Every bound is checked on both sides: the boundary value is accepted, a value just outside is
rejected with a message that names the problem. The bounds are those of
`coplane.estimation.limits`, so these tests read them from there rather than repeating numbers.
"""

from __future__ import annotations

import json
import math
import re
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import BaseModel, ValidationError

from coplane import ids
from coplane.estimation import limits
from coplane.messages import (
    MAX_RANGES,
    MAX_SATELLITES,
    DiagnosticsMessage,
    EpochTime,
    NodeMessage,
    PlaneReport,
    PlaneSummary,
    RangeReport,
    SatelliteColumns,
    SatelliteReport,
    SolutionMessage,
    SppReport,
    VehicleCounters,
    VehicleState,
    VelocityReport,
)
from tests.support.wire_payloads import node, plane, sat, satellites, solution, spp, state

JUST = 1.0 + 1e-9  # relative step just outside a bound


def rejects(model: type[BaseModel], data: dict[str, Any], match: str) -> None:
    """`model` refuses `data` and the error says `match` (a regex)."""
    with pytest.raises(ValidationError, match="(?s)" + match):
        model.model_validate(data)


def along_x(r: float) -> tuple[float, float, float]:
    """A point at exactly r metres from the Earth's centre (the radius check then has no rounding)."""
    return (r, 0.0, 0.0)


# -- the valid examples -------------------------------------------------------------------------


def test_examples_are_valid() -> None:
    """The example payloads these tests mutate are themselves accepted."""
    NodeMessage.model_validate(node())
    SolutionMessage.model_validate(solution())
    DiagnosticsMessage.model_validate(
        {
            "fleet": "f",
            "method": "pc",
            "pace": "lockstep",
            "epochs_solved": 0,
            "vehicles": {"u1": VehicleCounters()},
        }
    )


def test_sat_id_systems_are_the_known_systems() -> None:
    """The satellite-id rule and the known systems agree: every known system letter is a valid satellite id."""
    letters = set(re.findall(r"\[([A-Z]+)\]", limits.SAT_ID_PATTERN)[0])
    assert letters == set(limits.KNOWN_SYSTEMS)
    for s in sorted(limits.KNOWN_SYSTEMS):
        SatelliteReport.model_validate(sat(sat=f"{s}01"))


# -- ids ----------------------------------------------------------------------------------------


@pytest.mark.parametrize("vid", ["u1", "a", "A-b_9", "x" * 32, "0", "-", "_"])
def test_vehicle_id_accepted(vid: str) -> None:
    """Vehicle and fleet ids matching VEHICLE_ID_PATTERN (1..32 of [A-Za-z0-9_-]) are accepted."""
    assert ids.VEHICLE_ID.fullmatch(vid)
    NodeMessage.model_validate(node(vehicle_id=vid, fleet=vid, ranges=[]))
    RangeReport.model_validate({"to": vid, "range_m": 1.0, "sigma_m": 1.0})


@pytest.mark.parametrize("vid", ["", "x" * 33, "u 1", "u.1", "u/1", "u*", "ü1", "u1\n", " u1"])
def test_vehicle_id_rejected(vid: str) -> None:
    """Ids outside VEHICLE_ID_PATTERN (empty, too long, spaces, dots, slashes, wildcards, non-ASCII, newline) are rejected."""
    assert not ids.VEHICLE_ID.fullmatch(vid)
    rejects(NodeMessage, node(vehicle_id=vid), "vehicle_id")
    rejects(NodeMessage, node(fleet=vid), "fleet")
    rejects(RangeReport, {"to": vid, "range_m": 1.0, "sigma_m": 1.0}, "to")
    rejects(VehicleState, state(vehicle_id=vid), "vehicle_id")
    rejects(SolutionMessage, solution(missing=[vid]), "missing")


def test_vehicle_id_pattern_is_the_limits_one() -> None:
    """The pattern pydantic reports for a bad id is VEHICLE_ID_PATTERN itself."""
    rejects(RangeReport, {"to": "u 1", "range_m": 1.0, "sigma_m": 1.0}, re.escape(ids.VEHICLE_ID_PATTERN))


@pytest.mark.parametrize("sid", ["G01", "C63", "E36", "R24", "J07", "I14", "S20"])
def test_satellite_id_accepted(sid: str) -> None:
    """RINEX 3 satellite ids of the known systems are accepted (as report and as SPP exclusion)."""
    SatelliteReport.model_validate(sat(sat=sid))
    SppReport.model_validate(spp(excluded=[sid]))


@pytest.mark.parametrize("sid", ["G1", "G001", "g05", "X05", "05", "G 5", "GO5", "G05\n", ""])
def test_satellite_id_rejected(sid: str) -> None:
    """Malformed satellite ids and unknown systems are rejected with SAT_ID_PATTERN in the message."""
    rejects(SatelliteReport, sat(sat=sid), re.escape(limits.SAT_ID_PATTERN))
    rejects(SppReport, spp(excluded=[sid]), "excluded")


# -- satellites ---------------------------------------------------------------------------------


@pytest.mark.parametrize("r", limits.SAT_RADIUS_M)
def test_satellite_radius_boundary_accepted(r: float) -> None:
    """A satellite exactly at either end of SAT_RADIUS_M is accepted."""
    SatelliteReport.model_validate(sat(sat_pos_ecef_m=along_x(r)))


@pytest.mark.parametrize("r", [limits.SAT_RADIUS_M[0] / JUST, limits.SAT_RADIUS_M[1] * JUST, 0.0, 6.4e6])
def test_satellite_radius_outside_rejected(r: float) -> None:
    """A satellite position just outside SAT_RADIUS_M (or on the ground) is rejected, naming the satellite."""
    rejects(
        SatelliteReport,
        sat(sat="C14", sat_pos_ecef_m=along_x(r)),
        r"satellite C14 position is \d+ m from the Earth's centre \(expected 10000000\.\.50000000\)",
    )


def test_satellite_columns_keep_every_row_rule() -> None:
    """The wire's columns check each value as its row would, naming the column and the satellite's
    index; a satellite in the wrong orbit is named; the rows come back as they went in."""
    rows = [sat(), sat(sat="C14", doppler_hz=None, used=False, excluded_reason="excluded by RAIM")]
    cols = SatelliteColumns.model_validate(satellites(*rows))
    assert len(cols) == 2 and cols.sat == ["G05", "C14"] and cols.used == [True, False]
    assert [r.model_dump(exclude_defaults=True) for r in cols.rows()] == [
        SatelliteReport.model_validate(r).model_dump(exclude_defaults=True) for r in rows
    ]
    assert SatelliteColumns.from_rows(cols.rows()) == cols == SatelliteColumns.from_rows(rows)
    bad = satellites(*rows)
    bad["sigma_m"][1] = -1.0
    rejects(NodeMessage, node(satellites=bad), r"satellites\.sigma_m\.1")
    far = satellites(sat(), sat(sat="C14", sat_pos_ecef_m=along_x(6.4e6)))
    rejects(NodeMessage, node(satellites=far), r"satellite C14 position is \d+ m from the Earth's centre")


@pytest.mark.parametrize("column", list(SatelliteReport.model_fields))
def test_satellite_columns_of_another_length_rejected(column: str) -> None:
    """Every column has one value per satellite: one short or long column is refused, by name."""
    for cut in (-1, 1):
        bad = satellites(sat(), sat(sat="C14"))
        bad[column] = bad[column][:cut] if cut < 0 else [*bad[column], bad[column][0]]
        # the odd column is named; when that is `sat` itself, the first column that disagrees with it
        named = "column sat has" if column == "sat" else f"satellite column {column} has"
        rejects(NodeMessage, node(satellites=bad), named)


@pytest.mark.parametrize("field", ["pseudorange_m", "rho_m"])
def test_pseudorange_bounds(field: str) -> None:
    """Raw and corrected pseudoranges: PSEUDORANGE_M inclusive, just outside rejected."""
    lo, hi = limits.PSEUDORANGE_M
    for ok in (lo, hi):
        SatelliteReport.model_validate(sat(**{field: ok}))
    rejects(SatelliteReport, sat(**{field: lo / JUST}), f"{field}.*greater than or equal")
    rejects(SatelliteReport, sat(**{field: hi * JUST}), f"{field}.*less than or equal")


def test_satellite_clock_and_sigma_bounds() -> None:
    """Satellite clock within +-MAX_SAT_CLOCK_S and sigma in (0, MAX_SIGMA_M]."""
    c, s = limits.MAX_SAT_CLOCK_S, limits.MAX_SIGMA_M
    for ok in (-c, c):
        SatelliteReport.model_validate(sat(sat_clock_s=ok))
    rejects(SatelliteReport, sat(sat_clock_s=c * JUST), "sat_clock_s")
    rejects(SatelliteReport, sat(sat_clock_s=-c * JUST), "sat_clock_s")
    SatelliteReport.model_validate(sat(sigma_m=s))
    SatelliteReport.model_validate(sat(sigma_m=5e-324))
    rejects(SatelliteReport, sat(sigma_m=s * JUST), "sigma_m")
    rejects(SatelliteReport, sat(sigma_m=0.0), "sigma_m.*greater than 0")


@pytest.mark.parametrize(
    ("field", "lo", "hi"),
    [
        ("elevation_deg", -90.0, 90.0),
        ("azimuth_deg", 0.0, 360.0),
        ("cn0_dbhz", 0.0, 70.0),
        ("doppler_hz", -1e5, 1e5),
        ("tgd_m", -100.0, 100.0),
        ("iono_m", -100.0, 200.0),
        ("tropo_m", 0.0, 100.0),
        ("dgnss_m", -500.0, 500.0),
    ],
)
def test_satellite_field_bounds(field: str, lo: float, hi: float) -> None:
    """Angles, C/N0, Doppler and the per-satellite corrections accept their bounds and reject beyond."""
    for ok in (lo, hi):
        SatelliteReport.model_validate(sat(**{field: ok}))
    step = max(abs(lo), abs(hi), 1.0) * 1e-9
    rejects(SatelliteReport, sat(**{field: lo - step}), field)
    rejects(SatelliteReport, sat(**{field: hi + step}), field)


def test_optional_satellite_fields_may_be_missing() -> None:
    """Doppler, C/N0 and the DGNSS correction are optional (a receiver may not report them)."""
    m = SatelliteReport.model_validate(sat(doppler_hz=None, cn0_dbhz=None))
    assert m.doppler_hz is None and m.cn0_dbhz is None and m.dgnss_m is None and m.used is True


def test_excluded_reason_length() -> None:
    """An exclusion reason is at most 200 characters."""
    SatelliteReport.model_validate(sat(used=False, excluded_reason="x" * 200))
    rejects(SatelliteReport, sat(used=False, excluded_reason="x" * 201), "excluded_reason")


# -- SPP ----------------------------------------------------------------------------------------


def test_spp_fix_needs_a_position() -> None:
    """An ok SPP report without a position is rejected; a failed one needs none."""
    rejects(SppReport, spp(position_ecef_m=None), "an SPP fix needs position_ecef_m")
    m = SppReport.model_validate({"ok": False, "reason": "too few satellites"})
    assert m.position_ecef_m is None and m.n_used == 0


@pytest.mark.parametrize("r", limits.RECEIVER_RADIUS_M)
def test_spp_radius_boundary_accepted(r: float) -> None:
    """An SPP position exactly at either end of RECEIVER_RADIUS_M is accepted."""
    SppReport.model_validate(spp(position_ecef_m=along_x(r)))


@pytest.mark.parametrize("r", [limits.RECEIVER_RADIUS_M[0] / JUST, limits.RECEIVER_RADIUS_M[1] * JUST, 0.0])
def test_spp_radius_outside_rejected(r: float) -> None:
    """An SPP position just outside RECEIVER_RADIUS_M is rejected, also when the fix is not ok."""
    match = r"SPP position is \d+ m from the Earth's centre \(expected 5000000\.\.8000000\)"
    rejects(SppReport, spp(position_ecef_m=along_x(r)), match)
    rejects(SppReport, spp(ok=False, position_ecef_m=along_x(r)), match)


def test_spp_covariance_and_lists() -> None:
    """Covariance has exactly 9 entries; at most 4 clocks and MAX_SATELLITES exclusions; DOPs bounded."""
    rejects(SppReport, spp(covariance_m2=[1.0] * 8), "covariance_m2")
    rejects(SppReport, spp(covariance_m2=[1.0] * 10), "covariance_m2")
    SppReport.model_validate(spp(clocks_m={"G": 1.0, "C": 2.0, "E": 3.0, "R": 4.0}))
    rejects(SppReport, spp(clocks_m={"G": 1.0, "C": 2.0, "E": 3.0, "R": 4.0, "J": 5.0}), "clocks_m")
    SppReport.model_validate(spp(n_used=MAX_SATELLITES))
    rejects(SppReport, spp(n_used=MAX_SATELLITES + 1), "n_used")
    rejects(SppReport, spp(n_used=-1), "n_used")
    rejects(SppReport, spp(excluded=["G01"] * (MAX_SATELLITES + 1)), "excluded")
    SppReport.model_validate(spp(gdop=1e6))
    rejects(SppReport, spp(gdop=-0.1), "gdop")


# -- velocity -----------------------------------------------------------------------------------


def vel(**kw: Any) -> dict[str, Any]:
    d: dict[str, Any] = {
        "velocity_ecef_mps": (1.0, 2.0, 3.0),
        "sigma_mps": 0.1,
        "clock_drift_mps": 0.0,
        "n_used": 6,
    }
    d.update(kw)
    return d


def test_velocity_at_max_speed_accepted() -> None:
    """A speed of exactly MAX_SPEED_MPS is accepted (along an axis and as a 3-4-0 triangle)."""
    v = limits.MAX_SPEED_MPS
    VelocityReport.model_validate(vel(velocity_ecef_mps=(0.0, 0.0, -v)))
    VelocityReport.model_validate(vel(velocity_ecef_mps=(0.6 * v, 0.8 * v, 0.0)))


def test_velocity_above_max_speed_rejected() -> None:
    """A speed just above MAX_SPEED_MPS is rejected as not a road vehicle."""
    v = limits.MAX_SPEED_MPS * JUST
    rejects(
        VelocityReport, vel(velocity_ecef_mps=(v, 0.0, 0.0)), f"velocity above {limits.MAX_SPEED_MPS:.0f} m/s"
    )


def test_standstill_velocity_must_be_zero() -> None:
    """A standstill claim (coplane.gnss.standstill) lets the fusion hold the vehicle still: with a
    nonzero velocity it contradicts itself and is rejected, naming why."""
    VelocityReport.model_validate(vel(velocity_ecef_mps=(0.0, 0.0, 0.0), standstill=True))
    rejects(
        VelocityReport,
        vel(velocity_ecef_mps=(0.0, 1e-3, 0.0), standstill=True),
        "standstill velocity must be zero",
    )


def test_velocity_drift_sigma_bounds() -> None:
    """Clock drift within +-MAX_DRIFT_MPS; sigma in (0, 100]; n_used within 0..MAX_SATELLITES."""
    d = limits.MAX_DRIFT_MPS
    for ok in (-d, d):
        VelocityReport.model_validate(vel(clock_drift_mps=ok))
    rejects(VelocityReport, vel(clock_drift_mps=d * JUST), "clock_drift_mps")
    rejects(VelocityReport, vel(clock_drift_mps=-d * JUST), "clock_drift_mps")
    VelocityReport.model_validate(vel(sigma_mps=100.0))
    rejects(VelocityReport, vel(sigma_mps=0.0), "sigma_mps")
    rejects(VelocityReport, vel(sigma_mps=100.0 * JUST), "sigma_mps")
    rejects(VelocityReport, vel(n_used=MAX_SATELLITES + 1), "n_used")


# -- planes -------------------------------------------------------------------------------------


def test_unavailable_plane_needs_nothing() -> None:
    """An unavailable plane is valid without normal, offset or sigma (it only says why)."""
    p = PlaneReport.model_validate({"status": "unavailable", "reason": "too-few-points: 4 < 15"})
    assert p.normal is None and p.sigma_m is None


@pytest.mark.parametrize("status", ["available", "available-after-fe"])
@pytest.mark.parametrize("missing", ["normal", "d_antenna_m", "sigma_m"])
def test_available_plane_needs_normal_offset_sigma(status: str, missing: str) -> None:
    """An available plane lacking its normal, offset or sigma is rejected."""
    rejects(
        PlaneReport,
        plane(status=status, **{missing: None}),
        "an available plane needs normal, d_antenna_m and sigma_m",
    )


def test_plane_normal_must_be_unit() -> None:
    """A plane normal must be unit length to 1e-6: 1 +- 5e-7 accepted, 1 +- 2e-6 rejected with its length."""
    for scale in (1.0 + 5e-7, 1.0 - 5e-7):
        PlaneReport.model_validate(plane(normal=(0.0, 0.0, scale)))
    for scale in (1.0 + 2e-6, 1.0 - 2e-6, 0.5):
        rejects(
            PlaneReport, plane(normal=(0.0, 0.0, scale)), r"plane normal is not unit length \(\d\.\d{6}\)"
        )
    rejects(PlaneReport, plane(normal=(0.0, 0.0, 0.0)), "not unit length")


def test_plane_normal_checked_only_when_available() -> None:
    """An unavailable plane may carry the last (rejected) fit's non-unit normal: no unit check there."""
    PlaneReport.model_validate({"status": "unavailable", "normal": (0.0, 0.0, 2.0)})


def test_plane_sigma_and_status() -> None:
    """Plane sigma in (0, MAX_PLANE_SIGMA_M]; unknown status names are rejected."""
    s = limits.MAX_PLANE_SIGMA_M
    PlaneReport.model_validate(plane(sigma_m=s))
    rejects(PlaneReport, plane(sigma_m=s * JUST), "sigma_m")
    rejects(PlaneReport, plane(sigma_m=0.0), "sigma_m")
    rejects(PlaneReport, plane(status="maybe"), "status")
    rejects(PlaneReport, plane(n_points_used=-1), "n_points_used")
    rejects(PlaneReport, plane(residual_max_m=-1e-9), "residual_max_m")


# -- ranges and the node message ----------------------------------------------------------------


def test_range_bounds() -> None:
    """A range in (0, MAX_RANGE_M] with sigma in (0, MAX_RANGE_SIGMA_M] is accepted; outside rejected."""
    r, s = limits.MAX_RANGE_M, limits.MAX_RANGE_SIGMA_M
    RangeReport.model_validate({"to": "u2", "range_m": r, "sigma_m": s})
    rejects(RangeReport, {"to": "u2", "range_m": r * JUST, "sigma_m": 0.3}, "range_m")
    rejects(RangeReport, {"to": "u2", "range_m": 0.0, "sigma_m": 0.3}, "range_m")
    rejects(RangeReport, {"to": "u2", "range_m": 10.0, "sigma_m": s * JUST}, "sigma_m")
    rejects(RangeReport, {"to": "u2", "range_m": 10.0, "sigma_m": 0.0}, "sigma_m")


def test_duplicate_satellite_rejected() -> None:
    """The same satellite twice in one node message is rejected."""
    rejects(
        NodeMessage,
        node(satellites=satellites(sat(), sat(rho_m=2.3e7))),
        "duplicate satellite in one node message",
    )


def test_duplicate_peer_and_self_range_rejected() -> None:
    """A peer named twice, or a range to the vehicle itself, is rejected."""
    r = {"to": "u2", "range_m": 12.5, "sigma_m": 0.3}
    msg = "ranges must name each peer once and not the vehicle itself"
    rejects(NodeMessage, node(ranges=[r, {**r, "range_m": 13.0}]), msg)
    rejects(NodeMessage, node(ranges=[{**r, "to": "u1"}]), msg)


def test_node_list_lengths() -> None:
    """At most MAX_SATELLITES satellites and MAX_RANGES ranges in one node message."""
    sats = [sat(sat=f"{s}{n:02d}") for s in "GCE" for n in range(1, 23)][: MAX_SATELLITES + 1]
    NodeMessage.model_validate(node(satellites=satellites(*sats[:MAX_SATELLITES])))
    rejects(NodeMessage, node(satellites=satellites(*sats)), "satellites")
    ranges = [{"to": f"p{i}", "range_m": 10.0, "sigma_m": 0.3} for i in range(MAX_RANGES + 1)]
    NodeMessage.model_validate(node(ranges=ranges[:MAX_RANGES]))
    rejects(NodeMessage, node(ranges=ranges), "ranges")


def test_node_scalar_bounds() -> None:
    """seq >= 0, antenna height in [0, 10] m, epoch week/tow in range, sent time >= 0."""
    NodeMessage.model_validate(node(antenna_height_m=0.0))
    NodeMessage.model_validate(node(antenna_height_m=10.0))
    rejects(NodeMessage, node(antenna_height_m=10.0 * JUST), "antenna_height_m")
    rejects(NodeMessage, node(seq=-1), "seq")
    rejects(NodeMessage, node(sent_unix_s=-1.0), "sent_unix_s")
    EpochTime.model_validate({"week": 0, "tow": 0.0})
    EpochTime.model_validate({"week": 10000, "tow": math.nextafter(604800.0, 0.0)})
    rejects(EpochTime, {"week": 1, "tow": 604800.0}, "tow")
    rejects(EpochTime, {"week": 1, "tow": -1e-9}, "tow")
    rejects(EpochTime, {"week": -1, "tow": 0.0}, "week")
    rejects(EpochTime, {"week": 10001, "tow": 0.0}, "week")


def test_schema_tag() -> None:
    """The schema tag defaults, is written as `schema`, and another version is rejected."""
    m = NodeMessage.model_validate(node())
    assert json.loads(m.model_dump_json(by_alias=True))["schema"] == "coplane.node/2"
    NodeMessage.model_validate({**node(), "schema": "coplane.node/2"})
    # /1 carried an object per satellite: a sender of the old schema is refused, not misread
    rejects(NodeMessage, {**node(), "schema": "coplane.node/1"}, "schema")
    rejects(SolutionMessage, {**solution(), "schema": "coplane.node/2"}, "schema")


# -- model-wide rules ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("model", "data"),
    [
        (NodeMessage, node()),
        (SatelliteReport, sat()),
        (SppReport, spp()),
        (PlaneReport, plane()),
        (RangeReport, {"to": "u2", "range_m": 1.0, "sigma_m": 1.0}),
        (EpochTime, {"week": 1, "tow": 0.0}),
        (SolutionMessage, solution()),
        (VehicleState, state()),
        (PlaneSummary, {"status": "unavailable"}),
    ],
)
def test_extra_fields_forbidden(model: type[BaseModel], data: dict[str, Any]) -> None:
    """Every wire model refuses an unknown field (a typo or a newer sender is caught, not ignored)."""
    rejects(model, {**data, "surprise": 1}, "surprise.*Extra inputs are not permitted")


def test_nested_extra_field_forbidden() -> None:
    """An unknown field inside a nested model (a satellite of a node message) is refused too."""
    rejects(NodeMessage, node(satellites={**satellites(sat()), "snr": [40]}), "snr")


def test_models_are_frozen() -> None:
    """Wire objects cannot be changed after validation (steps share them between vehicles)."""
    m = NodeMessage.model_validate(node())
    with pytest.raises(ValidationError, match="frozen"):
        m.seq = 5  # type: ignore[misc]


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_non_finite_numbers_rejected(bad: float) -> None:
    """NaN and +-inf are rejected everywhere, also in fields without bounds."""
    rejects(SatelliteReport, sat(pseudorange_m=bad), "pseudorange_m")
    rejects(VelocityReport, vel(velocity_ecef_mps=(1.0, bad, 0.0)), "velocity_ecef_mps")
    rejects(PlaneReport, plane(d_antenna_m=bad), "d_antenna_m")
    rejects(PlaneReport, plane(normal=(0.0, bad, 1.0)), "normal")
    rejects(SppReport, spp(covariance_m2=[1.0] * 8 + [bad]), "covariance_m2")
    rejects(SppReport, spp(clocks_m={"G": bad}), "clocks_m")
    rejects(VehicleState, state(clocks_s={"G": bad}), "clocks_s")
    rejects(VehicleState, state(position_ecef_m=(bad, 0.0, 0.0)), "position_ecef_m")
    rejects(SolutionMessage, solution(oldest_node_sent_unix_s=bad), "oldest_node_sent_unix_s")
    rejects(PlaneSummary, {"status": "available", "residual_rms_m": bad}, "residual_rms_m")


def test_non_finite_json_tokens_rejected() -> None:
    """A JSON payload with NaN or Infinity tokens is rejected on the JSON path too."""
    raw = NodeMessage.model_validate(node()).model_dump_json(by_alias=True)
    for token in ("NaN", "Infinity", "-Infinity"):
        bad = raw.replace('"tgd_m":[1.2', f'"tgd_m":[{token}', 1)
        assert bad != raw
        with pytest.raises(ValidationError):
            NodeMessage.model_validate_json(bad)


def test_json_round_trip_is_exact() -> None:
    """A node and a solution message survive dump -> JSON -> validate unchanged, floats bit for bit."""
    awkward = [0.1 + 0.2, 1.0 / 3.0, 2.0**-1074, 1.7976931348623157e308, 6378137.000000001]
    m = NodeMessage.model_validate(
        node(
            antenna_height_m=1.0 / 3.0,
            spp=spp(covariance_m2=[*awkward, 1e-300, -0.0, 5e-324, 123456789.12345679]),
            satellites=satellites(
                sat(rho_m=22222222.222222224, sigma_m=0.1 + 0.2, sat_pos_ecef_m=(-1.2e7 / 7, 1.5e7, 1.8e7))
            ),
            sent_unix_s=1.7e9 + 1.0 / 3.0,
        )
    )
    back = NodeMessage.model_validate_json(m.model_dump_json(by_alias=True))
    assert back == m
    assert back.spp.covariance_m2 == m.spp.covariance_m2
    assert [x.hex() for x in back.spp.covariance_m2 or []] == [x.hex() for x in m.spp.covariance_m2 or []]
    s = SolutionMessage.model_validate(
        solution(vehicles=[state(covariance_m2=[*awkward, 0.0, 0.0, 0.0, 0.0])])
    )
    assert SolutionMessage.model_validate_json(s.model_dump_json(by_alias=True)) == s


@settings(max_examples=200, deadline=None)
@given(
    rho=st.floats(*limits.PSEUDORANGE_M),
    clock=st.floats(-limits.MAX_SAT_CLOCK_S, limits.MAX_SAT_CLOCK_S),
    sigma=st.floats(0.0, limits.MAX_SIGMA_M, exclude_min=True),
    el=st.floats(-90.0, 90.0),
)
def test_json_round_trip_any_satellite(rho: float, clock: float, sigma: float, el: float) -> None:
    """Any in-bounds satellite report round-trips through JSON to the identical floats."""
    m = SatelliteReport.model_validate(sat(rho_m=rho, sat_clock_s=clock, sigma_m=sigma, elevation_deg=el))
    back = SatelliteReport.model_validate_json(m.model_dump_json())
    assert (back.rho_m, back.sat_clock_s, back.sigma_m, back.elevation_deg) == (rho, clock, sigma, el)
    assert math.copysign(1.0, back.sat_clock_s) == math.copysign(1.0, clock)


def test_solution_fields() -> None:
    """A solution's method name is at most 64 chars, seq/solve time non-negative, covariance 9 entries."""
    SolutionMessage.model_validate(solution(method="m" * 64))
    rejects(SolutionMessage, solution(method="m" * 65), "method")
    rejects(SolutionMessage, solution(seq=-1), "seq")
    rejects(SolutionMessage, solution(solve_time_s=-0.001), "solve_time_s")
    rejects(VehicleState, state(covariance_m2=[0.0] * 8), "covariance_m2")
    rejects(VehicleState, state(n_ranges=-1), "n_ranges")
    rejects(VehicleState, state(plane_status="yes"), "plane_status")


def test_diagnostics_pace() -> None:
    """Diagnostics name the pace as lockstep or realtime only."""
    base = {"fleet": "f", "method": "pc", "epochs_solved": 0}
    for pace in ("lockstep", "realtime"):
        DiagnosticsMessage.model_validate({**base, "pace": pace})
    rejects(DiagnosticsMessage, {**base, "pace": "fast"}, "pace")


def test_diagnostics_cluster_workers() -> None:
    """A server cannot have lost more cluster workers than it has (the API's gauge subtracts)."""
    base = {"fleet": "f", "method": "pc", "pace": "lockstep", "epochs_solved": 0}
    d = DiagnosticsMessage.model_validate({**base, "cluster_workers": 3, "cluster_workers_lost": 3})
    assert (d.cluster_workers, d.cluster_workers_lost) == (3, 3)
    rejects(
        DiagnosticsMessage, {**base, "cluster_workers": 2, "cluster_workers_lost": 3}, "cluster_workers_lost"
    )
    rejects(DiagnosticsMessage, {**base, "cluster_workers": 0}, "cluster_workers")


def test_diagnostics_map_common_offset() -> None:
    """The road map's common residual: an offset comes with the passes it rests on, finite, bounded."""
    base = {"fleet": "f", "method": "pc", "pace": "lockstep", "epochs_solved": 0}
    assert DiagnosticsMessage.model_validate(base).map_common_offset_m is None
    d = DiagnosticsMessage.model_validate({**base, "map_common_offset_m": -0.4, "map_common_passes": 120})
    assert (d.map_common_offset_m, d.map_common_passes) == (-0.4, 120)
    for bad in (
        {"map_common_offset_m": 0.3},  # an offset resting on no passes
        {"map_common_passes": 30},  # passes without an offset
        {"map_common_offset_m": float("nan"), "map_common_passes": 30},
        {"map_common_offset_m": 5000.0, "map_common_passes": 30},
        {"map_common_offset_m": 0.1, "map_common_passes": -1},
    ):
        rejects(DiagnosticsMessage, {**base, **bad}, "map_common")


def test_diagnostics_map_counts_are_bounded() -> None:
    """What became of the map evidence: named counts, never negative, a bounded number of kinds."""
    base = {"fleet": "f", "method": "pc", "pace": "lockstep", "epochs_solved": 0}
    d = DiagnosticsMessage.model_validate({**base, "map_counts": {"samples": 3, "skipped:sigma-up": 3}})
    assert d.map_counts == {"samples": 3, "skipped:sigma-up": 3}
    for bad in (
        {"samples": -1},
        {"samples": 1.5},
        {"x" * 65: 1},
        {f"k{i}": 1 for i in range(65)},
    ):
        rejects(DiagnosticsMessage, {**base, "map_counts": bad}, "map_counts")


# -- the wire bounds against the estimators' input check ----------------------------------------


def _validated(sat_kw: dict[str, Any], spp_kw: dict[str, Any], range_m: float) -> Any:
    """Two node messages through FusionStep.inputs and validate_epoch (what an estimator keeps)."""
    from coplane.estimation.validate import validate_epoch
    from coplane.gtime import GpsTime
    from coplane.methods import get_method
    from coplane.steps import FusionStep

    r = {"to": "u2", "range_m": range_m, "sigma_m": 0.3}
    m1 = NodeMessage.model_validate(
        node(satellites=satellites(sat(**sat_kw)), spp=spp(**spp_kw), ranges=[r], plane=None)
    )
    m2 = NodeMessage.model_validate(node(vehicle_id="u2", ranges=[], plane=None))
    fusion = FusionStep("fleet-1", get_method("non-cp-ekf"))
    return validate_epoch(fusion.inputs(GpsTime(2320, 115800.0), {"u1": m1, "u2": m2}))


def test_interior_values_pass_validate_epoch() -> None:
    """Values well inside the wire bounds reach the estimator: nothing rejected or skipped."""
    v = _validated({}, {}, 12.5)
    assert not v.rejected and not v.skipped
    assert len(v.vehicles["u1"].pseudoranges) == 1 and len(v.ranges) == 1


@pytest.mark.parametrize(
    ("sat_kw", "spp_kw", "range_m"),
    [
        ({"sat_pos_ecef_m": along_x(limits.SAT_RADIUS_M[1])}, {}, 12.5),
        ({"rho_m": limits.PSEUDORANGE_M[1]}, {}, 12.5),
        ({"sat_clock_s": limits.MAX_SAT_CLOCK_S}, {}, 12.5),
        ({"sigma_m": limits.MAX_SIGMA_M}, {}, 12.5),
        ({}, {"position_ecef_m": along_x(limits.RECEIVER_RADIUS_M[1])}, 12.5),
        ({}, {}, limits.MAX_RANGE_M),
    ],
    ids=["sat-radius", "pseudorange", "sat-clock", "sigma", "spp-radius", "range"],
)
def test_boundary_values_pass_validate_epoch(
    sat_kw: dict[str, Any], spp_kw: dict[str, Any], range_m: float
) -> None:
    """A value exactly at a wire bound is also kept by validate_epoch (same limit, same inclusiveness)."""
    v = _validated(sat_kw, spp_kw, range_m)
    assert not v.rejected and not v.skipped
