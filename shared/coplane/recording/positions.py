"""Positions a user types or a RINEX header gives: a base antenna (`--base-position`), a static
receiver's surveyed point (`--truth ID=x,y,z`), the header's antenna reference point.

ECEF metres and geodetic degrees are told apart by magnitude, so either form works everywhere.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Literal

import numpy as np

from coplane.errors import ConfigError
from coplane.geo import enu_to_ecef, geodetic_to_ecef
from coplane.recording.model import ObsHeader

EARTH_RADIUS_RANGE_M = (6.30e6, 6.42e6)  # |ECEF| of a point near the surface


def parse_position(text: str) -> tuple[float, float, float] | Literal["header"]:
    """A base antenna position: "header", ECEF "x,y,z" (m) or geodetic "lat,lon,h" (deg, deg, m
    ellipsoidal), told apart by magnitude; ConfigError naming the forms otherwise."""
    if text.strip() == "header":
        return "header"
    try:
        vals = [float(v) for v in text.replace(" ", "").split(",")]
    except ValueError:
        vals = []
    if len(vals) == 3 and all(math.isfinite(v) for v in vals):
        norm = math.hypot(*vals)
        if EARTH_RADIUS_RANGE_M[0] <= norm <= EARTH_RADIUS_RANGE_M[1]:
            return (vals[0], vals[1], vals[2])
        if abs(vals[0]) <= 90.0 and abs(vals[1]) <= 180.0 and abs(vals[2]) < 1e4:
            xyz = geodetic_to_ecef(math.radians(vals[0]), math.radians(vals[1]), vals[2])
            return (float(xyz[0]), float(xyz[1]), float(xyz[2]))
    raise ConfigError(
        f"--base-position {text!r}: expected 'header', ECEF 'x,y,z' in metres or 'lat,lon,h' "
        "(degrees, degrees, ellipsoidal metres)"
    )


def parse_truth_value(text: str) -> Path | tuple[float, float, float]:
    """A `--truth ID=VALUE` value: three numbers are a surveyed point (ECEF or lat,lon,h, as
    `parse_position` tells them apart), anything else a reference trajectory file."""
    parts = [p.strip() for p in text.split(",")]
    if len(parts) not in (1, 3) and all(_is_number(p) for p in parts):
        raise ConfigError(
            f"--truth ...={text}: a surveyed point is three numbers, x,y,z (m) or lat,lon,h; got {len(parts)}"
        )
    if len(parts) == 3:
        try:
            point = parse_position(text)
        except ConfigError:
            return Path(text)
        assert point != "header"
        return point
    return Path(text)


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def header_antenna_position(h: ObsHeader, path: Path) -> tuple[float, float, float]:
    """The antenna reference point from a header: APPROX POSITION XYZ (the marker) moved by
    ANTENNA: DELTA H/E/N (up, east, north), as RINEX defines them."""
    if h.approx_position_ecef_m is None:
        raise ConfigError(f"{path}: its header has no APPROX POSITION XYZ; give --base-position x,y,z")
    up, east, north = h.antenna_delta_hen_m
    xyz = enu_to_ecef(np.array([east, north, up]), np.array(h.approx_position_ecef_m))
    return (float(xyz[0]), float(xyz[1]), float(xyz[2]))
