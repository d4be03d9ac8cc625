"""WGS-84 frames: ECEF, geodetic and local East-North-Up.

Conversions of points use pymap3d (well kept, vectorised); the ENU rotation matrix (the paper's
S, eq. 1) is three lines of trigonometry and is written here because pymap3d does not expose it.
"""

from __future__ import annotations

import math

import numpy as np
import pymap3d as pm
from numpy.typing import ArrayLike, NDArray

WGS84_A = 6378137.0
WGS84_F = 1.0 / 298.257223563
OMEGA_E_WGS84 = 7.2921151467e-5  # rad/s (GPS); BeiDou's CGCS2000 uses the same value


_E2 = WGS84_F * (2.0 - WGS84_F)
_B = WGS84_A * (1.0 - WGS84_F)
_EP2 = (WGS84_A**2 - _B**2) / _B**2


def _geodetic_scalar(x: float, y: float, z: float) -> tuple[float, float, float]:
    """Heikkinen's closed form (exact to ~1e-9 m near the Earth's surface).

    Written here rather than calling pymap3d because SPP converts a point every iteration of
    every epoch: pymap3d's generic vectorised path costs ~0.2 ms a call, this ~2 us.
    """
    p2 = x * x + y * y
    p = math.sqrt(p2)
    if p < 1e-9:  # on the polar axis
        return (math.copysign(math.pi / 2, z), 0.0, abs(z) - _B)
    z2 = z * z
    f = 54.0 * _B * _B * z2
    g = p2 + (1.0 - _E2) * z2 - _E2 * (WGS84_A**2 - _B**2)
    c = _E2 * _E2 * f * p2 / (g * g * g)
    s = (1.0 + c + math.sqrt(c * c + 2.0 * c)) ** (1.0 / 3.0)
    k = s + 1.0 + 1.0 / s
    pp = f / (3.0 * k * k * g * g)
    q = math.sqrt(1.0 + 2.0 * _E2 * _E2 * pp)
    r0 = -(pp * _E2 * p) / (1.0 + q) + math.sqrt(
        max(0.5 * WGS84_A**2 * (1.0 + 1.0 / q) - pp * (1.0 - _E2) * z2 / (q * (1.0 + q)) - 0.5 * pp * p2, 0.0)
    )
    u = math.sqrt((p - _E2 * r0) ** 2 + z2)
    v = math.sqrt((p - _E2 * r0) ** 2 + (1.0 - _E2) * z2)
    z0 = _B * _B * z / (WGS84_A * v)
    h = u * (1.0 - _B * _B / (WGS84_A * v))
    lat = math.atan((z + _EP2 * z0) / p)
    return (lat, math.atan2(y, x), h)


def ecef_to_geodetic(xyz: ArrayLike) -> NDArray[np.float64]:
    """ECEF (..., 3) m -> (..., 3) [lat rad, lon rad, ellipsoidal height m]."""
    p = np.asarray(xyz, dtype=float)
    if p.shape == (3,):
        return np.array(_geodetic_scalar(float(p[0]), float(p[1]), float(p[2])))
    lat, lon, h = pm.ecef2geodetic(p[..., 0], p[..., 1], p[..., 2], deg=False)
    # pymap3d hands back 0-d values for length-1 inputs: restore the input's leading shape
    shape = p.shape[:-1]
    return np.stack([np.reshape(lat, shape), np.reshape(lon, shape), np.reshape(h, shape)], axis=-1)


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
    """Unit ellipsoidal normal (local up) at an ECEF point (3,), or at each of (N, 3) points.

    The third row of `enu_rotation` at Heikkinen's latitude and longitude, point by point: the
    plane history converts a fleet solution's few points per epoch, where pymap3d's vectorised
    path costs ~0.2 ms a call in guards and setup, and this costs ~2 us a point.
    """
    p = np.asarray(xyz, dtype=float)
    if p.shape == (3,):
        lat, lon, _ = _geodetic_scalar(float(p[0]), float(p[1]), float(p[2]))
        cl = math.cos(lat)
        return np.array([cl * math.cos(lon), cl * math.sin(lon), math.sin(lat)])
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"points must have shape (3,) or (N, 3), got {p.shape}")
    out = np.empty(p.shape)
    for i, (x, y, z) in enumerate(p.tolist()):
        lat, lon, _ = _geodetic_scalar(x, y, z)
        cl = math.cos(lat)
        out[i] = (cl * math.cos(lon), cl * math.sin(lon), math.sin(lat))
    return out


def ecef_to_enu(xyz: ArrayLike, ref_ecef: ArrayLike) -> NDArray[np.float64]:
    """ECEF points (..., 3) to ENU (..., 3) about `ref_ecef`."""
    ref = np.asarray(ref_ecef, dtype=float)
    lat, lon, _ = ecef_to_geodetic(ref)
    return (np.asarray(xyz, dtype=float) - ref) @ enu_rotation(lat, lon).T


def enu_to_ecef(enu: ArrayLike, ref_ecef: ArrayLike) -> NDArray[np.float64]:
    ref = np.asarray(ref_ecef, dtype=float)
    lat, lon, _ = ecef_to_geodetic(ref)
    return np.asarray(enu, dtype=float) @ enu_rotation(lat, lon) + ref
