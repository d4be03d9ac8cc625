"""The global metric grid: keys, round trips, tile sizes, neighbourhoods, boxes, edge cases."""

from __future__ import annotations

import math

import numpy as np
import pytest

from coplane.geo import geodetic_to_ecef
from coplane.roadmap import (
    TileKey,
    tile_centre,
    tile_corners_lonlat,
    tile_of_ecef,
    tile_of_geodetic,
    tiles_around,
    tiles_in_bbox,
)
from coplane.roadmap.grid import EARTH_RADIUS_M

SIZE = 20.0


def test_key_text_round_trips_with_negative_numbers() -> None:
    for key in (TileKey(0, 0), TileKey(-12, 40), TileKey(267_000, -1_000_001)):
        assert TileKey.parse(str(key)) == key
    assert str(TileKey(-12, 40)) == "r-12c40"
    assert TileKey(1, 2) < TileKey(1, 3) < TileKey(2, -5)  # ordered by row, then column
    for bad in ("", "r1", "r1c", "rc2", "r1.5c2", "c2r1", "r1c2x"):
        with pytest.raises(ValueError, match="not a tile key"):
            TileKey.parse(bad)


PLACES = [(48.137, 11.575), (-33.87, 151.21), (0.0, 0.0), (60.0, -179.9999), (-84.9, -70.0), (35.68, 139.69)]


@pytest.mark.parametrize("lat_deg, lon_deg", PLACES)
def test_a_point_lies_in_its_tile_and_the_centre_maps_back(lat_deg: float, lon_deg: float) -> None:
    lat, lon = math.radians(lat_deg), math.radians(lon_deg)
    key = tile_of_geodetic(lat, lon, SIZE)
    ring = tile_corners_lonlat(key, SIZE)
    assert len(ring) == 5 and ring[0] == ring[-1]
    lons, lats = [p[0] for p in ring], [p[1] for p in ring]
    assert min(lons) <= lon_deg < max(lons) and min(lats) <= lat_deg < max(lats)
    assert tile_of_geodetic(*tile_centre(key, SIZE), SIZE) == key
    # the same key from ECEF at any height
    assert tile_of_ecef(geodetic_to_ecef(lat, lon, 812.0), SIZE) == key


def test_tiles_are_size_m_square_within_a_percent() -> None:
    for lat_deg in (0.0, 45.0, 70.0):
        key = tile_of_geodetic(math.radians(lat_deg), 0.3, SIZE)
        (lo0, la0), (lo1, _), (_, la1) = tile_corners_lonlat(key, SIZE)[:3]
        p00 = geodetic_to_ecef(math.radians(la0), math.radians(lo0), 0.0)
        p10 = geodetic_to_ecef(math.radians(la0), math.radians(lo1), 0.0)
        p01 = geodetic_to_ecef(math.radians(la1), math.radians(lo0), 0.0)
        # WGS-84 radii differ from the grid's sphere by at most ~0.7 %
        assert np.linalg.norm(p10 - p00) == pytest.approx(SIZE, rel=0.01)
        assert np.linalg.norm(p01 - p00) == pytest.approx(SIZE, rel=0.01)


def test_neighbouring_tiles_share_edges() -> None:
    key = tile_of_geodetic(math.radians(48.1), math.radians(11.5), SIZE)
    ring = tile_corners_lonlat(key, SIZE)
    east = tile_corners_lonlat(TileKey(key.row, key.col + 1), SIZE)
    north = tile_corners_lonlat(TileKey(key.row + 1, key.col), SIZE)
    assert east[0] == pytest.approx(ring[1]) and east[3] == pytest.approx(ring[2])
    assert north[0][1] == pytest.approx(ring[3][1])  # rows stack exactly; columns shift per row


def test_the_poles_are_refused() -> None:
    with pytest.raises(ValueError, match="outside the map grid"):
        tile_of_geodetic(math.radians(85.5), 0.0, SIZE)
    with pytest.raises(ValueError, match="outside the map grid"):
        tile_of_ecef(np.array([0.0, 0.0, 6_356_752.0]), SIZE)
    with pytest.raises(ValueError, match="outside the map grid"):
        tile_centre(TileKey(round(math.radians(86) * EARTH_RADIUS_M / SIZE), 0), SIZE)


def test_longitude_wraps() -> None:
    a = tile_of_geodetic(0.5, math.radians(190.0), SIZE)
    b = tile_of_geodetic(0.5, math.radians(-170.0), SIZE)
    assert a == b


def test_tiles_around_cover_the_disc_and_no_more() -> None:
    lat, lon = math.radians(48.137), math.radians(11.575)
    p = geodetic_to_ecef(lat, lon, 500.0)
    assert tiles_around(p, 0.0, SIZE) == [tile_of_geodetic(lat, lon, SIZE)]
    r = 35.0
    around = tiles_around(p, r, SIZE)
    assert around == sorted(set(around))
    # every point of the disc (sampled) is in a listed tile
    for ang in np.linspace(0, 2 * math.pi, 72, endpoint=False):
        for rr in (r * 0.5, r * 0.999):
            dlat = rr * math.sin(ang) / EARTH_RADIUS_M
            dlon = rr * math.cos(ang) / (EARTH_RADIUS_M * math.cos(lat))
            assert tile_of_geodetic(lat + dlat, lon + dlon, SIZE) in around
    # and no listed tile is entirely far away: its centre within r + half a diagonal
    for key in around:
        clat, clon = tile_centre(key, SIZE)
        dy = (clat - lat) * EARTH_RADIUS_M
        dx = (clon - lon) * EARTH_RADIUS_M * math.cos(clat)
        assert math.hypot(dx, dy) <= r + SIZE / math.sqrt(2) + 1e-6
    assert len(around) < (2 * r / SIZE + 2) ** 2


def test_tiles_in_bbox_and_its_limit() -> None:
    box = (11.5750, 48.1370, 11.5760, 48.1375)  # ~74 m x 56 m
    keys = tiles_in_bbox(*box, SIZE)
    assert keys == sorted(set(keys)) and 12 <= len(keys) <= 30
    for lon in np.linspace(box[0], box[2], 9):
        for lat in np.linspace(box[1], box[3], 9):
            assert tile_of_geodetic(math.radians(lat), math.radians(lon), SIZE) in keys
    with pytest.raises(ValueError, match="more than the limit of 10"):
        tiles_in_bbox(*box, SIZE, limit=10)
    with pytest.raises(ValueError, match="not a lon/lat box"):
        tiles_in_bbox(11.6, 48.0, 11.5, 48.1, SIZE)
