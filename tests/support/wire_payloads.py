"""Valid example payloads of the wire models (`coplane.messages`), as dicts for tests to mutate:
each builder takes keyword overrides (merged over its defaults)."""

from __future__ import annotations

from typing import Any

from coplane.messages import SatelliteColumns

RX = (-2169358.0, 4387164.0, 4076272.0)  # a receiver on the ground (about 6.37e6 m from the centre)
SAT = (-1.2e7, 1.5e7, 1.8e7)  # a GNSS satellite (about 2.63e7 m)


def sat(**kw: Any) -> dict[str, Any]:
    return {
        "sat": "G05",
        "pseudorange_m": 2.2e7,
        "doppler_hz": -1234.5,
        "cn0_dbhz": 42.0,
        "elevation_deg": 35.0,
        "azimuth_deg": 120.0,
        "sat_pos_ecef_m": SAT,
        "sat_clock_s": 1e-4,
        "tgd_m": 1.2,
        "iono_m": 3.4,
        "tropo_m": 2.5,
        "rho_m": 2.2e7 - 7.0,
        "sigma_m": 1.5,
    } | kw


def satellites(*rows: dict[str, Any]) -> dict[str, list[Any]]:
    """A node message's satellites as the wire carries them (`SatelliteColumns`): one list per
    field, from rows such as `sat()`, not validated, so that tests can build bad ones too."""
    return SatelliteColumns.data_of(rows)


def spp(**kw: Any) -> dict[str, Any]:
    return {
        "ok": True,
        "position_ecef_m": RX,
        "covariance_m2": [1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0],
    } | kw


def plane(**kw: Any) -> dict[str, Any]:
    return {
        "status": "available",
        "normal": (0.6, 0.0, 0.8),
        "d_antenna_m": -6.37e6,
        "sigma_m": 0.2,
    } | kw


def node(**kw: Any) -> dict[str, Any]:
    return {
        "fleet": "fleet-1",
        "vehicle_id": "u1",
        "seq": 0,
        "epoch": {"week": 2320, "tow": 115800.0},
        "rx_time": {"week": 2320, "tow": 115800.004},
        "antenna_height_m": 1.7,
        "spp": spp(),
        "velocity": {
            "velocity_ecef_mps": (1.0, 2.0, 3.0),
            "sigma_mps": 0.1,
            "clock_drift_mps": 50.0,
            "n_used": 8,
        },
        "satellites": satellites(sat(), sat(sat="C14")),
        "plane": plane(),
        "ranges": [{"to": "u2", "range_m": 12.5, "sigma_m": 0.3}],
    } | kw


def state(**kw: Any) -> dict[str, Any]:
    return {
        "vehicle_id": "u1",
        "position_ecef_m": RX,
        "antenna_height_m": 1.7,
        "n_pseudoranges": 8,
        "n_ranges": 1,
        "plane_used": True,
        "has_gnss_fix": True,
    } | kw


def solution(**kw: Any) -> dict[str, Any]:
    return {
        "fleet": "fleet-1",
        "method": "pc",
        "seq": 3,
        "epoch": {"week": 2320, "tow": 115803.0},
        "vehicles": [state()],
        "solve_time_s": 0.01,
    } | kw
