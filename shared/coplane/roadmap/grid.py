"""A global grid of near-square tiles of a chosen edge in metres (docs/roadmap.md, "Grid").

Rows are bands of latitude `size_m` tall on a sphere of radius R = 6371 km: row = floor(lat R /
size). Within a row the column width is `size_m` at the row's central latitude: col =
floor(lon R cos(lat_c) / size). So every tile is `size_m` by `size_m` to within the change of
cos(lat) across one row (2e-6 relative for 20 m at 45 deg), keys are two integers anyone can
compute without a library, and the neighbours of a point are a few ranges of integers.

Why not H3: its cells are hexagons whose sizes step by fixed factors (~7 in area per resolution,
~2.6 in edge), so "20 m tiles" is not available; it is a compiled dependency; and a tile here is a
plane regression in its own local frame, for which a square of known size is the natural unit.

The sphere only scales angles to metres; positions are geodetic (WGS-84 latitude and longitude).
Near the poles (|lat| > 85 deg) columns degenerate and the grid refuses. Longitude is taken in
[-180, 180) deg; the last column of a row before the antimeridian is narrower than the others.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numpy.typing import ArrayLike

from coplane.geo import ecef_to_geodetic, enu_rotation, geodetic_to_ecef
from coplane.typing import Mat, Vec

EARTH_RADIUS_M = 6371000.0
MAX_LAT_RAD = math.radians(85.0)
_KEY = re.compile(r"^r(-?\d+)c(-?\d+)$")


@dataclass(frozen=True, order=True)
class TileKey:
    """One tile: its row (latitude band) and column within the row; str form "r{row}c{col}"."""

    row: int
    col: int

    def __str__(self) -> str:
        return f"r{self.row}c{self.col}"

    @classmethod
    def parse(cls, text: str) -> TileKey:
        """The inverse of `str`, e.g. "r-12c40"; ValueError naming the text otherwise."""
        m = _KEY.match(text.strip()) if isinstance(text, str) else None
        if m is None:
            raise ValueError(f"not a tile key (r<row>c<col>): {text!r}")
        return cls(int(m.group(1)), int(m.group(2)))


def _check_lat(lat_rad: float) -> None:
    if not math.isfinite(lat_rad) or abs(lat_rad) > MAX_LAT_RAD:
        raise ValueError(
            f"latitude {math.degrees(lat_rad):.4f} deg is outside the map grid (|lat| <= 85 deg)"
        )


def _wrap_lon(lon_rad: float) -> float:
    if not math.isfinite(lon_rad):
        raise ValueError(f"longitude is not finite: {lon_rad!r}")
    return (lon_rad + math.pi) % (2.0 * math.pi) - math.pi


def row_centre_lat(row: int, size_m: float) -> float:
    """Latitude (rad) of the middle of a row: the latitude its columns are measured at."""
    return (row + 0.5) * size_m / EARTH_RADIUS_M


def _col_width_rad(row: int, size_m: float) -> float:
    lat_c = row_centre_lat(row, size_m)
    _check_lat(lat_c)
    return size_m / (EARTH_RADIUS_M * math.cos(lat_c))


def _row(lat_rad: float, size_m: float) -> int:
    return math.floor(lat_rad * EARTH_RADIUS_M / size_m)


def tile_of_geodetic(lat_rad: float, lon_rad: float, size_m: float) -> TileKey:
    """The tile holding a geodetic position."""
    _check_lat(lat_rad)
    row = _row(lat_rad, size_m)
    return TileKey(row, math.floor(_wrap_lon(lon_rad) / _col_width_rad(row, size_m)))


def tile_of_ecef(ecef: ArrayLike, size_m: float) -> TileKey:
    """The tile holding an ECEF position (its latitude and longitude; the height does not matter)."""
    lat, lon, _ = ecef_to_geodetic(np.asarray(ecef, dtype=float))
    return tile_of_geodetic(float(lat), float(lon), size_m)


def tile_centre(key: TileKey, size_m: float) -> tuple[float, float]:
    """(lat_rad, lon_rad) of a tile's centre: the origin of its local frame."""
    w = _col_width_rad(key.row, size_m)
    return row_centre_lat(key.row, size_m), (key.col + 0.5) * w


def tile_corners_lonlat(key: TileKey, size_m: float) -> list[tuple[float, float]]:
    """The tile's outline as a closed, counter-clockwise ring of 5 (lon_deg, lat_deg) (GeoJSON order)."""
    w = _col_width_rad(key.row, size_m)
    lat0, lat1 = key.row * size_m / EARTH_RADIUS_M, (key.row + 1) * size_m / EARTH_RADIUS_M
    lon0, lon1 = key.col * w, (key.col + 1) * w
    ring = [(lon0, lat0), (lon1, lat0), (lon1, lat1), (lon0, lat1), (lon0, lat0)]
    return [(math.degrees(lo), math.degrees(la)) for lo, la in ring]


@lru_cache(maxsize=4096)
def _frame(row: int, col: int, size_m: float) -> tuple[Vec, Mat]:
    lat, lon = tile_centre(TileKey(row, col), size_m)
    origin = geodetic_to_ecef(lat, lon, 0.0)
    rot = enu_rotation(lat, lon)
    origin.flags.writeable = False
    rot.flags.writeable = False
    return origin, rot


def tile_frame(key: TileKey, size_m: float) -> tuple[Vec, Mat]:
    """(ECEF point at the tile centre on the ellipsoid, ENU rotation there): a tile's local frame is
    enu = rot @ (p - origin), with up the ellipsoidal height to ~15 um inside the tile. Cached,
    read-only arrays: every sample and every plane query of a tile needs them."""
    return _frame(key.row, key.col, float(size_m))


def tiles_around(ecef: ArrayLike, radius_m: float, size_m: float) -> list[TileKey]:
    """Every tile with a point within `radius_m` (horizontally) of an ECEF position, sorted."""
    if not (math.isfinite(radius_m) and radius_m >= 0.0):
        raise ValueError(f"radius_m must be a finite number >= 0, got {radius_m!r}")
    lat, lon, _ = (float(v) for v in ecef_to_geodetic(np.asarray(ecef, dtype=float)))
    _check_lat(lat)
    lon = _wrap_lon(lon)
    y = lat * EARTH_RADIUS_M
    out: list[TileKey] = []
    for row in range(math.floor((y - radius_m) / size_m), math.floor((y + radius_m) / size_m) + 1):
        dy = max(row * size_m - y, 0.0, y - (row + 1) * size_m)  # distance to the row's band
        half = math.sqrt(max(radius_m * radius_m - dy * dy, 0.0))
        x = lon * EARTH_RADIUS_M * math.cos(row_centre_lat(row, size_m))
        _check_lat(row_centre_lat(row, size_m))
        for col in range(math.floor((x - half) / size_m), math.floor((x + half) / size_m) + 1):
            out.append(TileKey(row, col))
    return sorted(out)


def row_col_ranges(
    min_lon_deg: float, min_lat_deg: float, max_lon_deg: float, max_lat_deg: float, size_m: float
) -> list[tuple[int, int, int]]:
    """(row, first col, last col) of the tiles meeting a lon/lat box: what `tiles_in_bbox` lists,
    and what a database queries row by row on its (row, col) index."""
    vals = (min_lon_deg, min_lat_deg, max_lon_deg, max_lat_deg)
    if not all(math.isfinite(v) for v in vals) or min_lon_deg > max_lon_deg or min_lat_deg > max_lat_deg:
        raise ValueError(f"not a lon/lat box (min_lon, min_lat, max_lon, max_lat): {vals}")
    if min_lon_deg < -180.0 or max_lon_deg > 180.0:
        raise ValueError(f"longitudes must be within [-180, 180] deg: {vals}")
    lat0, lat1 = math.radians(min_lat_deg), math.radians(max_lat_deg)
    _check_lat(lat0)
    _check_lat(lat1)
    out = []
    for row in range(_row(lat0, size_m), _row(lat1, size_m) + 1):
        w = _col_width_rad(row, size_m)
        c0 = math.floor(math.radians(min_lon_deg) / w)
        c1 = math.floor(math.radians(max_lon_deg) / w)
        out.append((row, c0, c1))
    return out


def tiles_in_bbox(
    min_lon_deg: float,
    min_lat_deg: float,
    max_lon_deg: float,
    max_lat_deg: float,
    size_m: float,
    limit: int = 100000,
) -> list[TileKey]:
    """Every tile meeting a lon/lat box, sorted; ValueError when that is more than `limit` tiles
    (a box of a whole country at 20 m would be billions)."""
    ranges = row_col_ranges(min_lon_deg, min_lat_deg, max_lon_deg, max_lat_deg, size_m)
    n = sum(c1 - c0 + 1 for _, c0, c1 in ranges)
    if n > limit:
        raise ValueError(f"the box meets {n} tiles, more than the limit of {limit}")
    return [TileKey(row, col) for row, c0, c1 in ranges for col in range(c0, c1 + 1)]
