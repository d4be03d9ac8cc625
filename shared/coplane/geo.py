"""WGS-84 frames: ECEF, geodetic and local East-North-Up.

Conversions of points use pymap3d (well kept, vectorised); the ENU rotation matrix (the paper's
S, eq. 1) is three lines of trigonometry and is written here because pymap3d does not expose it.
"""

from __future__ import annotations

import numpy as np
import pymap3d as pm
from numpy.typing import ArrayLike, NDArray

WGS84_A = 6378137.0
WGS84_F = 1.0 / 298.257223563
OMEGA_E_WGS84 = 7.2921151467e-5  # rad/s (GPS); BeiDou's CGCS2000 uses the same value


def ecef_to_geodetic(xyz: ArrayLike) -> NDArray[np.float64]:
    """ECEF (..., 3) m -> (..., 3) [lat rad, lon rad, ellipsoidal height m]."""
    p = np.asarray(xyz, dtype=float)
    lat, lon, h = pm.ecef2geodetic(p[..., 0], p[..., 1], p[..., 2], deg=False)
    return np.stack([np.asarray(lat), np.asarray(lon), np.asarray(h)], axis=-1)


def geodetic_to_ecef(lat: float, lon: float, h: float) -> NDArray[np.float64]:
    """Geodetic (radians, metres) -> ECEF metres."""
    x, y, z = pm.geodetic2ecef(lat, lon, h, deg=False)
    return np.array([x, y, z], dtype=float)


def enu_rotation(lat: float, lon: float) -> NDArray[np.float64]:
    """Rows are the E, N, U unit vectors in ECEF: enu = R @ (ecef - ref); ecef_delta = R.T @ enu."""
    sl, cl = np.sin(lat), np.cos(lat)
    so, co = np.sin(lon), np.cos(lon)
    return np.array([[-so, co, 0.0], [-sl * co, -sl * so, cl], [cl * co, cl * so, sl]])


def up_vector(xyz: ArrayLike) -> NDArray[np.float64]:
    """Unit ellipsoidal normal (local up) at an ECEF point."""
    lat, lon, _ = ecef_to_geodetic(xyz)
    return enu_rotation(lat, lon)[2]


def ecef_to_enu(xyz: ArrayLike, ref_ecef: ArrayLike) -> NDArray[np.float64]:
    """ECEF points (..., 3) to ENU (..., 3) about `ref_ecef`."""
    ref = np.asarray(ref_ecef, dtype=float)
    lat, lon, _ = ecef_to_geodetic(ref)
    return (np.asarray(xyz, dtype=float) - ref) @ enu_rotation(lat, lon).T


def enu_to_ecef(enu: ArrayLike, ref_ecef: ArrayLike) -> NDArray[np.float64]:
    ref = np.asarray(ref_ecef, dtype=float)
    lat, lon, _ = ecef_to_geodetic(ref)
    return np.asarray(enu, dtype=float) @ enu_rotation(lat, lon) + ref


def azimuth_elevation(rx_ecef: ArrayLike, sat_ecef: ArrayLike) -> tuple[float, float]:
    """Azimuth and elevation (radians) of a satellite seen from a receiver."""
    rx = np.asarray(rx_ecef, dtype=float)
    d = np.asarray(sat_ecef, dtype=float) - rx
    if float(np.dot(rx, rx)) < 1.0:  # receiver position unknown: RTKLIB convention
        return 0.0, np.pi / 2
    lat, lon, _ = ecef_to_geodetic(rx)
    e, n, u = enu_rotation(lat, lon) @ (d / np.linalg.norm(d))
    az = float(np.arctan2(e, n)) % (2 * np.pi)
    return az, float(np.arcsin(np.clip(u, -1.0, 1.0)))
