"""Frames: the fast geodetic conversion against pymap3d, ENU rotation properties."""

import numpy as np
import pymap3d as pm
import pytest
from hypothesis import given
from hypothesis import strategies as st

from coplane.geo import (
    ecef_to_enu,
    ecef_to_geodetic,
    enu_rotation,
    enu_to_ecef,
    geodetic_to_ecef,
    up_vector,
)


@given(st.floats(-89.999, 89.999), st.floats(-180, 180), st.floats(-500.0, 30000.0))
def test_geodetic_round_trip_matches_pymap3d(lat_deg: float, lon_deg: float, h: float) -> None:
    x, y, z = pm.geodetic2ecef(lat_deg, lon_deg, h)
    lat, lon, hh = ecef_to_geodetic([x, y, z])
    assert abs(np.degrees(lat) - lat_deg) < 1e-9
    assert abs(((np.degrees(lon) - lon_deg) + 180) % 360 - 180) < 1e-9
    assert abs(hh - h) < 1e-6
    ref = pm.ecef2geodetic(x, y, z, deg=False)
    assert abs(lat - ref[0]) < 1e-11 and abs(hh - ref[2]) < 1e-6  # pymap3d itself is ~1e-9 m off


def test_poles_and_vectorised_path() -> None:
    lat, _, h = ecef_to_geodetic([0.0, 0.0, 6356752.314245 + 10.0])
    assert abs(lat - np.pi / 2) < 1e-12 and abs(h - 10.0) < 1e-6
    pts = np.array([geodetic_to_ecef(0.3, 1.1, 50.0), geodetic_to_ecef(-0.7, -2.0, 5.0)])
    out = ecef_to_geodetic(pts)
    assert out.shape == (2, 3) and abs(out[1, 2] - 5.0) < 1e-6
    one = ecef_to_geodetic(pts[:1])  # a one-vehicle fleet solution (regression: pymap3d 0-d output)
    assert one.shape == (1, 3) and abs(one[0, 2] - 50.0) < 1e-6


def test_enu_rotation_is_orthonormal_and_round_trips() -> None:
    r = enu_rotation(0.7, 2.0)
    assert np.allclose(r @ r.T, np.eye(3), atol=1e-15)
    ref = geodetic_to_ecef(0.7, 2.0, 30.0)
    p = ref + np.array([10.0, -3.0, 2.0])
    assert np.allclose(enu_to_ecef(ecef_to_enu(p, ref), ref), p, atol=1e-8)
    up = ecef_to_enu(geodetic_to_ecef(0.7, 2.0, 40.0), ref)
    assert np.allclose(up, [0, 0, 10.0], atol=1e-6)


def test_vectorised_sagnac_ranges_equal_the_scalar_geodist() -> None:
    from coplane.gnss.ephemeris import geometric_range
    from coplane.gnss.geometry import sagnac_ranges

    rng = np.random.default_rng(1)
    rx = geodetic_to_ecef(0.69, 2.03, 50.0)
    sats = rng.normal(size=(12, 3))
    sats = 2.6e7 * sats / np.linalg.norm(sats, axis=1)[:, None]
    r, e = sagnac_ranges(sats, rx)
    for i in range(len(sats)):
        ri, ei = geometric_range(sats[i], rx)
        assert abs(r[i] - ri) < 1e-6 and np.allclose(e[i], ei, atol=1e-12)


def test_up_vector_one_and_many_points() -> None:
    """(N, 3) gives each point's (3,) up, which is enu_rotation's up row, and agrees with pymap3d."""
    rng = np.random.default_rng(3)
    lat, lon, h = rng.uniform(-1.5, 1.5, 500), rng.uniform(-3.14, 3.14, 500), rng.uniform(-400, 5000, 500)
    pts = np.stack(pm.geodetic2ecef(lat, lon, h, deg=False), axis=-1)
    many = up_vector(pts)
    assert many.shape == (500, 3)
    want = np.stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)], axis=-1)
    np.testing.assert_allclose(many, want, atol=1e-12)
    for p, u in zip(pts[:50], many[:50], strict=True):
        la, lo, _ = ecef_to_geodetic(p)
        assert np.array_equal(up_vector(p), u)
        np.testing.assert_allclose(u, enu_rotation(la, lo)[2], atol=1e-15)
    polar = np.array([[0.0, 0.0, 6356752.3 + 5.0], [0.0, 0.0, -6356752.3 - 5.0]])
    np.testing.assert_allclose(up_vector(polar), [[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]], atol=1e-15)
    assert up_vector(np.empty((0, 3))).shape == (0, 3)
    with pytest.raises(ValueError, match="shape"):
        up_vector(np.zeros((2, 2)))
