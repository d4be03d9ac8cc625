"""Broadcast ionosphere (GPS and BeiDou Klobuchar) and Saastamoinen troposphere delays.

All angles are radians; delays are metres of code delay on the named frequency. The GPS model
and the troposphere reproduce RTKLIB 2.4.3 `ionmodel`/`tropmodel` (tests/gnss/test_atmosphere.py:
< 1 um). BeiDou's Klobuchar variant differs from GPS's in geometry (a proper ionospheric pierce
point at 375 km on a 6378 km sphere), uses geographic (not geomagnetic) latitude, BDT, and a
clamp on the period, so it is implemented separately from the BDS-SIS-ICD.
"""

from __future__ import annotations

import logging
import math

from coplane.gnss.constants import FREQ_BDS_B1I, FREQ_GPS_L1, C
from coplane.gtime import GpsTime, gpst_to_bdt
from coplane.recording.model import IonoCoefficients, NavData

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


def _usable(c: IonoCoefficients | None) -> bool:
    return c is not None and any(v != 0.0 for v in (*c.alpha, *c.beta))


def klobuchar_gps_m(
    t: GpsTime, lat: float, lon: float, az: float, el: float, coeffs: IonoCoefficients
) -> float:
    """GPS L1 ionospheric delay (IS-GPS-200 20.3.3.5.2.5), as RTKLIB `ionmodel`.

    Works in semicircles like the ICD; GPS time of day drives the diurnal cosine.
    Returns 0 for satellites at or below the horizon.
    """
    if el <= 0.0:
        return 0.0
    a0, a1, a2, a3 = coeffs.alpha
    b0, b1, b2, b3 = coeffs.beta
    psi = 0.0137 / (el / math.pi + 0.11) - 0.022  # Earth-centred angle
    phi = lat / math.pi + psi * math.cos(az)  # sub-ionospheric latitude
    phi = max(-0.416, min(0.416, phi))
    lam = lon / math.pi + psi * math.sin(az) / math.cos(phi * math.pi)
    phi += 0.064 * math.cos((lam - 1.617) * math.pi)  # geomagnetic latitude
    tt = 43200.0 * lam + t.tow  # local time
    tt -= math.floor(tt / 86400.0) * 86400.0
    f = 1.0 + 16.0 * (0.53 - el / math.pi) ** 3  # slant factor
    amp = max(0.0, a0 + phi * (a1 + phi * (a2 + phi * a3)))
    per = max(72000.0, b0 + phi * (b1 + phi * (b2 + phi * b3)))
    x = 2.0 * math.pi * (tt - 50400.0) / per
    if abs(x) < 1.57:
        return C * f * (NIGHT_DELAY_S + amp * (1.0 + x * x * (-0.5 + x * x / 24.0)))
    return C * f * NIGHT_DELAY_S


def klobuchar_bds_m(
    t: GpsTime, lat: float, lon: float, az: float, el: float, coeffs: IonoCoefficients
) -> float:
    """BeiDou B1I ionospheric delay from the BDS broadcast Klobuchar model (BDS-SIS-ICD 5.2.4.7).

    Pierce point on a 375 km shell over a 6378 km sphere; amplitude and period are polynomials
    in |geographic latitude of the pierce point| (semicircles); local time from BDT.
    Returns 0 for satellites at or below the horizon. The ICD's arcsin longitude formula is
    kept as written: for a pierce point beyond the pole (above ~70 deg latitude, looking
    poleward at low elevation) it picks the user's meridian instead of the opposite one.
    """
    if el <= 0.0:
        return 0.0
    k = BDS_IONO_EARTH_RADIUS_M / (BDS_IONO_EARTH_RADIUS_M + BDS_IONO_HEIGHT_M) * math.cos(el)
    psi = math.pi / 2.0 - el - math.asin(k)  # Earth-centred angle user -> pierce point
    sin_phi = math.sin(lat) * math.cos(psi) + math.cos(lat) * math.sin(psi) * math.cos(az)
    phi_m = math.asin(max(-1.0, min(1.0, sin_phi)))
    s = math.sin(psi) * math.sin(az) / math.cos(phi_m)
    lam_m = lon + math.asin(max(-1.0, min(1.0, s)))
    sow = gpst_to_bdt(t)[1]
    tl = (sow + lam_m * 43200.0 / math.pi) % 86400.0  # local time at the pierce point
    x = abs(phi_m / math.pi)
    a0, a1, a2, a3 = coeffs.alpha
    b0, b1, b2, b3 = coeffs.beta
    amp = max(0.0, a0 + x * (a1 + x * (a2 + x * a3)))
    per = min(172800.0, max(72000.0, b0 + x * (b1 + x * (b2 + x * b3))))
    vertical = NIGHT_DELAY_S
    if abs(tl - 50400.0) < per / 4.0:
        vertical += amp * math.cos(2.0 * math.pi * (tl - 50400.0) / per)
    return C * vertical / math.sqrt(1.0 - k * k)


def iono_delay_m(
    system: str, t: GpsTime, lat: float, lon: float, az: float, el: float, nav: NavData
) -> float:
    """Broadcast ionospheric delay for the single-frequency code of `system` (GPS L1, BDS B1I).

    BeiDou uses its own coefficients ("C") when present, otherwise the GPS model scaled to B1I
    by (f_L1/f_B1I)^2 (which is what RTKLIB always does). Other L1-band systems use the GPS
    model. Without usable coefficients (absent or all zero) this returns 0 and logs one
    warning per system: uncorrected, not guessed (RTKLIB would use its 2004 defaults,
    `RTKLIB_DEFAULT_GPS_KLOBUCHAR`).
    """
    gps = nav.iono.get("G")
    if system == "C":
        bds = nav.iono.get("C")
        if bds is not None and _usable(bds):
            return klobuchar_bds_m(t, lat, lon, az, el, bds)
        if gps is not None and _usable(gps):
            return klobuchar_gps_m(t, lat, lon, az, el, gps) * GPS_L1_TO_BDS_B1I
    elif system in ("G", "J", "E", "S") and gps is not None and _usable(gps):
        return klobuchar_gps_m(t, lat, lon, az, el, gps)
    if system not in _warned:
        _warned.add(system)
        log.warning("no broadcast ionosphere coefficients for system %s: iono delay set to 0", system)
    return 0.0


def saastamoinen_m(lat: float, h: float, el: float, humidity: float = 0.7) -> float:
    """Slant tropospheric delay (m): Saastamoinen with a standard atmosphere, as RTKLIB `tropmodel`.

    Pressure and temperature come from the height (ellipsoidal, as RTKLIB uses it), 15 degC at
    sea level, with relative `humidity`. Returns 0 outside -100 m..10 km or at/below horizon.
    """
    if h < -100.0 or h > 1e4 or el <= 0.0:
        return 0.0
    hgt = max(0.0, h)
    pres = 1013.25 * (1.0 - 2.2557e-5 * hgt) ** 5.2568
    temp = 15.0 - 6.5e-3 * hgt + 273.16
    e = 6.108 * humidity * math.exp((17.15 * temp - 4684.0) / (temp - 38.45))
    cos_z = math.cos(math.pi / 2.0 - el)
    trph = 0.0022768 * pres / (1.0 - 0.00266 * math.cos(2.0 * lat) - 0.00028 * hgt / 1e3) / cos_z
    trpw = 0.002277 * (1255.0 / temp + 0.05) * e / cos_z
    return trph + trpw
