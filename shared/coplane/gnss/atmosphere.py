"""Broadcast ionosphere (GPS and BeiDou Klobuchar) and Saastamoinen troposphere delays.

All angles are radians; delays are metres of code delay on the named frequency. The GPS model
and the troposphere reproduce RTKLIB 2.4.3 `ionmodel`/`tropmodel` (tests/gnss/test_atmosphere.py:
< 1 um). BeiDou's Klobuchar variant differs from GPS's in geometry (a proper ionospheric pierce
point at 375 km on a 6378 km sphere), uses geographic (not geomagnetic) latitude, BDT, and a
clamp on the period, so it is implemented separately from the BDS-SIS-ICD.

Each model takes one satellite's azimuth/elevation as floats or an epoch's as arrays (same maths,
elementwise): `geometry.broadcast_delays` evaluates a whole system in one call per model.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass
from types import SimpleNamespace
from typing import Any, TypeVar

import numpy as np

from coplane.gnss.constants import FREQ_BDS_B1I, FREQ_GPS_L1, C
from coplane.gtime import GpsTime, gpst_to_bdt
from coplane.recording.model import IonoCoefficients, NavData
from coplane.typing import Vec

log = logging.getLogger(__name__)

NIGHT_DELAY_S = 5e-9  # Klobuchar constant night-time vertical delay (both ICDs)

# BDS-SIS-ICD B1I 5.2.4.7: thin-shell ionosphere
BDS_IONO_EARTH_RADIUS_M = 6378.0e3
BDS_IONO_HEIGHT_M = 375.0e3

# RTKLIB `ionmodel` falls back to these (2004/1/1) when the navigation file has no GPS
# coefficients; we return 0 instead (see `iono_delay_m`), but keep them for RTKLIB-like runs.
RTKLIB_DEFAULT_GPS_KLOBUCHAR = IonoCoefficients(
    alpha=(0.1118e-07, -0.7451e-08, -0.5961e-07, 0.1192e-06),
    beta=(0.1167e06, -0.2294e06, -0.1311e06, 0.1049e07),
)

# B1I delay from the GPS L1 model: the first-order delay scales with 1/f^2
GPS_L1_TO_BDS_B1I = (FREQ_GPS_L1 / FREQ_BDS_B1I) ** 2

_warned: set[str] = set()

Angles = TypeVar("Angles", float, Vec)  # one satellite (float) or an epoch's satellites (array)
Model = Callable[[Any, Any, Any], Any]  # (math or _NUMPY, el, az) -> delay, elementwise

# the numpy twins of the `math` functions the models use, under math's names (np.asin is numpy 2 only)
_NUMPY = SimpleNamespace(sin=np.sin, cos=np.cos, asin=np.arcsin, sqrt=np.sqrt, floor=np.floor)

# Arrays of fewer satellites go one by one through `math`: ~2.5 us per satellite against a fixed
# ~30 us for a Klobuchar on numpy arrays of up to a few dozen (~0.5 us per numpy call, ~55 calls).
# The troposphere's few numpy calls cost less than two satellites one by one.
VECTORISE_FROM = 16
VECTORISE_TROPO_FROM = 2


def _usable(c: IonoCoefficients | None) -> bool:
    return c is not None and any(v != 0.0 for v in (*c.alpha, *c.beta))


def _zeros_like(el: Angles) -> Angles:
    """A zero delay of `el`'s kind (float or array), for satellites a model does not correct."""
    return np.zeros(el.shape) if isinstance(el, np.ndarray) else 0.0


def _clip(v: Any, lo: float, hi: float | None = None) -> Any:
    """`v` limited to [lo, hi]: Python's max/min for floats, so scalar results keep their exact
    bits, np.maximum/np.minimum for arrays (a quarter of np.clip's overhead on an epoch's size)."""
    if isinstance(v, np.ndarray):
        return np.maximum(v if hi is None else np.minimum(v, hi), lo)
    return max(lo, v if hi is None else min(hi, v))


def _on_visible(
    model: Model, el: Angles, az: Angles | None = None, vectorise_from: int = VECTORISE_FROM
) -> Angles:
    """`model(xp, el, az)` for satellites above the horizon, 0 at or below it.

    One model body serves a satellite and a whole epoch: a float goes through `math` (bit for bit
    the former scalar code, which the simulator's outputs depend on), an array through numpy on
    its visible elements only (numpy's SIMD asin/pow may differ from libm in the last bit), or
    element by element through `math` when it is shorter than `vectorise_from`.
    """
    if isinstance(el, np.ndarray):
        if el.size < vectorise_from:
            azs = [None] * el.size if az is None else np.asarray(az).ravel().tolist()
            one = [_on_visible(model, e, a) for e, a in zip(el.ravel().tolist(), azs, strict=True)]
            return np.array(one, dtype=np.float64).reshape(el.shape)
        down = el <= 0.0  # (a NaN elevation gives NaN, as in the scalar code)
        if not down.any():  # the usual case: no gather/scatter
            return np.asarray(model(_NUMPY, el, az), dtype=np.float64)
        up = ~down
        out = np.zeros(el.shape)
        if up.any():
            out[up] = model(_NUMPY, el[up], None if az is None else np.asarray(az)[up])
        return out
    return 0.0 if el <= 0.0 else float(model(math, el, az))


def klobuchar_gps_m(
    t: GpsTime, lat: float, lon: float, az: Angles, el: Angles, coeffs: IonoCoefficients
) -> Angles:
    """GPS L1 ionospheric delay (IS-GPS-200 20.3.3.5.2.5), as RTKLIB `ionmodel`.

    Works in semicircles like the ICD; GPS time of day drives the diurnal cosine.
    Returns 0 for satellites at or below the horizon. `az`/`el`: floats or arrays (elementwise).
    """
    a0, a1, a2, a3 = coeffs.alpha
    b0, b1, b2, b3 = coeffs.beta

    def model(xp: Any, el: Any, az: Any) -> Any:
        el_sc = el / math.pi  # semicircles
        psi = 0.0137 / (el_sc + 0.11) - 0.022  # Earth-centred angle
        phi = _clip(lat / math.pi + psi * xp.cos(az), -0.416, 0.416)  # sub-ionospheric latitude
        lam = lon / math.pi + psi * xp.sin(az) / xp.cos(phi * math.pi)
        phi = phi + 0.064 * xp.cos((lam - 1.617) * math.pi)  # geomagnetic latitude
        tt = 43200.0 * lam + t.tow  # local time
        tt = tt - xp.floor(tt / 86400.0) * 86400.0
        f = 1.0 + 16.0 * (0.53 - el_sc) ** 3  # slant factor
        amp = _clip(a0 + phi * (a1 + phi * (a2 + phi * a3)), 0.0)
        per = _clip(b0 + phi * (b1 + phi * (b2 + phi * b3)), 72000.0)
        x = 2.0 * math.pi * (tt - 50400.0) / per
        x2 = x * x
        day = abs(x) < 1.57  # the cosine term only within its quarter period, as the ICD's branch
        return C * f * (NIGHT_DELAY_S + amp * (1.0 + x2 * (-0.5 + x2 / 24.0)) * day)

    return _on_visible(model, el, az)


def klobuchar_bds_m(
    t: GpsTime, lat: float, lon: float, az: Angles, el: Angles, coeffs: IonoCoefficients
) -> Angles:
    """BeiDou B1I ionospheric delay from the BDS broadcast Klobuchar model (BDS-SIS-ICD 5.2.4.7).

    Pierce point on a 375 km shell over a 6378 km sphere; amplitude and period are polynomials
    in |geographic latitude of the pierce point| (semicircles); local time from BDT.
    Returns 0 for satellites at or below the horizon. The ICD's arcsin longitude formula is
    kept as written: for a pierce point beyond the pole (above ~70 deg latitude, looking
    poleward at low elevation) it picks the user's meridian instead of the opposite one.
    `az`/`el`: floats or arrays (elementwise).
    """
    a0, a1, a2, a3 = coeffs.alpha
    b0, b1, b2, b3 = coeffs.beta
    sow = gpst_to_bdt(t)[1]

    def model(xp: Any, el: Any, az: Any) -> Any:
        k = BDS_IONO_EARTH_RADIUS_M / (BDS_IONO_EARTH_RADIUS_M + BDS_IONO_HEIGHT_M) * xp.cos(el)
        psi = math.pi / 2.0 - el - xp.asin(k)  # Earth-centred angle user -> pierce point
        sin_phi = math.sin(lat) * xp.cos(psi) + math.cos(lat) * xp.sin(psi) * xp.cos(az)
        phi_m = xp.asin(_clip(sin_phi, -1.0, 1.0))
        s = xp.sin(psi) * xp.sin(az) / xp.cos(phi_m)
        lam_m = lon + xp.asin(_clip(s, -1.0, 1.0))
        tl = (sow + lam_m * 43200.0 / math.pi) % 86400.0  # local time at the pierce point
        x = abs(phi_m / math.pi)
        amp = _clip(a0 + x * (a1 + x * (a2 + x * a3)), 0.0)
        per = _clip(b0 + x * (b1 + x * (b2 + x * b3)), 72000.0, 172800.0)
        dt = tl - 50400.0  # from 14:00 local time
        day = abs(dt) < per / 4.0  # the cosine term only within its quarter period
        vertical = NIGHT_DELAY_S + amp * xp.cos(2.0 * math.pi * dt / per) * day
        return C * vertical / xp.sqrt(1.0 - k * k)

    return _on_visible(model, el, az)


@dataclass(frozen=True)
class IonoModel:
    """Which broadcast model corrects a system's code: `klobuchar` (a model function taking
    t, lat, lon, az, el, coeffs), its coefficients, and the factor applied to its output."""

    klobuchar: Callable[..., Any]
    coeffs: IonoCoefficients
    scale: float = 1.0


def iono_model_for(system: str, nav: NavData, rtklib: bool = False) -> IonoModel | None:
    """The model of `iono_delay_m` for `system`, or None (uncorrected; warned once per system).

    BeiDou uses its own coefficients ("C") when present, otherwise the GPS model scaled to B1I
    by (f_L1/f_B1I)^2 (which is what RTKLIB always does, and `rtklib` asks for). Other L1-band
    systems use the GPS model."""
    gps = nav.iono.get("G")
    gps_ok = gps is not None and _usable(gps)
    if system == "C":
        bds = nav.iono.get("C")
        if rtklib and gps is not None:  # RTKLIB: the GPS coefficients as they are
            return IonoModel(klobuchar_gps_m, gps, GPS_L1_TO_BDS_B1I)
        if bds is not None and _usable(bds):
            return IonoModel(klobuchar_bds_m, bds)
        if gps is not None and gps_ok:
            return IonoModel(klobuchar_gps_m, gps, GPS_L1_TO_BDS_B1I)
    elif system in ("G", "J", "E", "S") and gps is not None and gps_ok:
        return IonoModel(klobuchar_gps_m, gps)
    if system not in _warned:
        _warned.add(system)
        log.warning("no broadcast ionosphere coefficients for system %s: iono delay set to 0", system)
    return None


def iono_delay_m(
    system: str, t: GpsTime, lat: float, lon: float, az: Angles, el: Angles, nav: NavData
) -> Angles:
    """Broadcast ionospheric delay for the single-frequency code of `system` (GPS L1, BDS B1I).

    The model is `iono_model_for`'s. Without usable coefficients (absent or all zero) this
    returns 0 and logs one warning per system: uncorrected, not guessed (RTKLIB would use its
    2004 defaults, `RTKLIB_DEFAULT_GPS_KLOBUCHAR`). `az`/`el`: floats or arrays of satellites of
    `system`.
    """
    model = iono_model_for(system, nav)
    if model is None:
        return _zeros_like(el)
    out = model.klobuchar(t, lat, lon, az, el, model.coeffs)
    return out * model.scale if model.scale != 1.0 else out


def saastamoinen_m(lat: float, h: float, el: Angles, humidity: float = 0.7) -> Angles:
    """Slant tropospheric delay (m): Saastamoinen with a standard atmosphere, as RTKLIB `tropmodel`.

    Pressure and temperature come from the height (ellipsoidal, as RTKLIB uses it), 15 degC at
    sea level, with relative `humidity`. Returns 0 outside -100 m..10 km or at/below horizon.
    `el`: a float or an array (elementwise); the receiver (`lat`, `h`) is one.
    """
    if h < -100.0 or h > 1e4:
        return _zeros_like(el)
    hgt = max(0.0, h)
    pres = 1013.25 * (1.0 - 2.2557e-5 * hgt) ** 5.2568
    temp = 15.0 - 6.5e-3 * hgt + 273.16
    e = 6.108 * humidity * math.exp((17.15 * temp - 4684.0) / (temp - 38.45))
    hydro = 0.0022768 * pres / (1.0 - 0.00266 * math.cos(2.0 * lat) - 0.00028 * hgt / 1e3)
    wet = 0.002277 * (1255.0 / temp + 0.05) * e

    def model(xp: Any, el: Any, az: Any) -> Any:
        cos_z = xp.cos(math.pi / 2.0 - el)
        return hydro / cos_z + wet / cos_z

    return _on_visible(model, el, vectorise_from=VECTORISE_TROPO_FROM)
