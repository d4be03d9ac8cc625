"""Ionosphere and troposphere models: GPS Klobuchar and Saastamoinen against RTKLIB, BeiDou
Klobuchar against ICD properties and an independent vector re-derivation."""

from __future__ import annotations

import functools
import itertools
import logging
import math
from typing import Literal

import numpy as np
import pytest
from support import rtklib_ref as ref

from coplane.gnss import atmosphere
from coplane.gnss.atmosphere import (
    GPS_L1_TO_BDS_B1I,
    RTKLIB_DEFAULT_GPS_KLOBUCHAR,
    iono_delay_m,
    klobuchar_bds_m,
    klobuchar_gps_m,
    saastamoinen_m,
)
from coplane.gnss.constants import C
from coplane.gnss.geometry import SkyView, broadcast_delays
from coplane.gtime import GpsTime
from coplane.recording.model import IonoCoefficients, NavData

# broadcast sets typed in from the nav headers of the real data
GPS_NAGOYA = IonoCoefficients(  # matrtklib_nagoya_static_20240624/base.nav
    alpha=(1.8626e-08, 2.2352e-08, -1.1921e-07, -5.9605e-08),
    beta=(1.2902e05, 1.6384e05, -1.9661e05, -2.6214e05),
)
GPS_HKSC = IonoCoefficients(  # hk_klt_20210610_f9p_rover_hksc_base/hksc1610.nav
    alpha=(0.5588e-08, 0.1490e-07, -0.5961e-07, -0.1192e-06),
    beta=(0.8397e05, 0.9830e05, -0.6554e05, -0.5243e06),
)
BDS_HKSC = IonoCoefficients(
    alpha=(0.9313e-08, 0.4470e-07, -0.3576e-06, 0.5961e-06),
    beta=(0.1188e06, 0.1638e06, -0.3277e06, 0.1966e06),
)
NIGHT_M = 5e-9 * C
D = math.radians


# --- GPS Klobuchar vs RTKLIB ionmodel ---------------------------------------------------------


def test_klobuchar_gps_matches_rtklib_ionmodel() -> None:
    lats = [D(v) for v in (-89.0, -60.0, -25.0, 0.0, 22.3, 35.1, 60.0, 89.0)]
    lons = [D(v) for v in (-179.0, -90.0, 0.0, 45.0, 114.2, 137.0)]
    azs = [D(v) for v in range(0, 360, 45)]
    els = [D(v) for v in (0.5, 5.0, 15.0, 30.0, 60.0, 90.0)]
    tows = [0.0, 21600.0, 43200.0, 50400.0, 64800.0, 604799.5]
    worst, n = 0.0, 0
    for coeffs in (GPS_NAGOYA, GPS_HKSC, RTKLIB_DEFAULT_GPS_KLOBUCHAR):
        for lat, lon, az, el, tow in itertools.product(lats, lons, azs, els, tows):
            t = GpsTime(2320, tow)
            ours = klobuchar_gps_m(t, lat, lon, az, el, coeffs)
            theirs = ref.ionmodel(t, coeffs, lat, lon, 10.0, az, el)
            worst = max(worst, abs(ours - theirs))
            n += 1
    print(f"\nklobuchar_gps_m vs RTKLIB ionmodel: {n} cases, max |diff| {worst:.2e} m")
    assert worst < 1e-6


def test_klobuchar_gps_below_horizon_is_zero() -> None:
    t = GpsTime(2320, 50400.0)
    assert klobuchar_gps_m(t, 0.6, 2.4, 1.0, 0.0, GPS_NAGOYA) == 0.0
    assert klobuchar_gps_m(t, 0.6, 2.4, 1.0, -0.1, GPS_NAGOYA) == 0.0


# --- BeiDou Klobuchar -------------------------------------------------------------------------

R_E, H_ION = 6378.0e3, 375.0e3


def _obliquity(el: float) -> float:
    return 1.0 / math.sqrt(1.0 - (R_E / (R_E + H_ION) * math.cos(el)) ** 2)


def _gpst_for_bdt_sow(sow_bdt: float) -> GpsTime:
    return GpsTime(2161, sow_bdt + 14.0)  # BDT = GPST - 14 s


def test_klobuchar_bds_night_is_constant_5ns() -> None:
    """At night only the 5 ns floor remains, scaled by the thin-shell obliquity.

    "Night" is |t - 14:00| >= A4/4: with the shortest period (A4 = 72000 s) that is 19:00-09:00
    local; with the broadcast HKSC set at the equator only about 00:00-06:00.
    """
    short_period = IonoCoefficients(BDS_HKSC.alpha, (72000.0, 0.0, 0.0, 0.0))
    t = _gpst_for_bdt_sow(86400.0 * 3)  # 00:00 BDT: at longitude 0 the pierce points are near midnight
    for lat, az, el in itertools.product(
        (-1.0, 0.0, 0.4, 1.2), (0.0, 1.0, 3.0, 5.5), (0.1, 0.5, 1.2, math.pi / 2)
    ):
        delay = klobuchar_bds_m(t, lat, 0.0, az, el, short_period)
        assert delay == pytest.approx(NIGHT_M * _obliquity(el), rel=1e-12)
    t_night = _gpst_for_bdt_sow(86400.0 * 3 + 3 * 3600.0)  # 03:00 local at the zenith of longitude 0
    assert klobuchar_bds_m(t_night, 0.0, 0.0, 0.0, math.pi / 2, BDS_HKSC) == pytest.approx(
        1.4989622900, abs=1e-9
    )


def test_klobuchar_bds_zenith_at_14h_is_polynomial_peak() -> None:
    """At zenith the pierce point is the user; at 14:00 local the cosine is 1: 5 ns + A2."""
    lat, lon = D(22.3), D(114.2)
    t = _gpst_for_bdt_sow(86400.0 * 2 + (50400.0 - lon * 43200.0 / math.pi))
    x = abs(lat / math.pi)
    a2 = sum(a * x**i for i, a in enumerate(BDS_HKSC.alpha))
    assert klobuchar_bds_m(t, lat, lon, 0.7, math.pi / 2, BDS_HKSC) == pytest.approx(
        (5e-9 + a2) * C, rel=1e-9
    )


def test_klobuchar_bds_scales_with_alpha_and_clamps() -> None:
    lat, lon, az, el = D(22.3), D(114.2), D(200.0), D(35.0)
    t = _gpst_for_bdt_sow(86400.0 * 2 + 6 * 3600.0)  # ~ 14:00 local in Hong Kong
    base = klobuchar_bds_m(t, lat, lon, az, el, BDS_HKSC)
    night = NIGHT_M * _obliquity(el)
    assert base > night + 1.0  # daytime excess present
    double = IonoCoefficients(tuple(2 * a for a in BDS_HKSC.alpha), BDS_HKSC.beta)  # type: ignore[arg-type]
    assert klobuchar_bds_m(t, lat, lon, az, el, double) - night == pytest.approx(
        2 * (base - night), rel=1e-12
    )
    negative = IonoCoefficients((-1e-7, 0.0, 0.0, 0.0), BDS_HKSC.beta)
    assert klobuchar_bds_m(t, lat, lon, az, el, negative) == pytest.approx(night, rel=1e-12)  # A2 < 0 -> 0
    # period clamps: A4 >= 172800 -> 172800, A4 < 72000 -> 72000
    for huge, cap in ((1e7, 172800.0), (1000.0, 72000.0)):
        a = IonoCoefficients(BDS_HKSC.alpha, (huge, 0.0, 0.0, 0.0))
        b = IonoCoefficients(BDS_HKSC.alpha, (cap, 0.0, 0.0, 0.0))
        assert klobuchar_bds_m(t, lat, lon, az, el, a) == klobuchar_bds_m(t, lat, lon, az, el, b)


def test_klobuchar_bds_symmetries() -> None:
    """Mirroring the line of sight about the equator mirrors the pierce point: same |latitude|,
    same longitude, same delay."""
    t = _gpst_for_bdt_sow(86400.0 * 2 + 20000.0)
    for az, el in itertools.product((D(10.0), D(60.0), D(135.0)), (D(10.0), D(40.0), D(75.0))):
        assert klobuchar_bds_m(t, 0.0, 2.0, az, el, BDS_HKSC) == pytest.approx(
            klobuchar_bds_m(t, 0.0, 2.0, math.pi - az, el, BDS_HKSC), rel=1e-12
        )
        assert klobuchar_bds_m(t, 0.5, 2.0, az, el, BDS_HKSC) == pytest.approx(
            klobuchar_bds_m(t, -0.5, 2.0, math.pi - az, el, BDS_HKSC), rel=1e-12
        )


def _bds_by_vectors(
    sow_bdt: float, lat: float, lon: float, az: float, el: float, c: IonoCoefficients
) -> tuple[float, bool]:
    """Independent re-derivation: intersect the line of sight with the 375 km shell in 3-D.

    Also says whether the pierce point lies beyond the pole (longitude more than 90 deg from the
    user's), where the ICD's arcsin formula picks the other meridian by construction.
    """
    up = np.array([math.cos(lat) * math.cos(lon), math.cos(lat) * math.sin(lon), math.sin(lat)])
    east = np.array([-math.sin(lon), math.cos(lon), 0.0])
    north = np.cross(up, east)
    d = math.cos(el) * (math.sin(az) * east + math.cos(az) * north) + math.sin(el) * up
    u = R_E * up
    # |u + s d| = R + h  ->  s^2 + 2 s (u.d) + |u|^2 - (R+h)^2 = 0
    b = float(u @ d)
    s = -b + math.sqrt(b * b - (R_E**2 - (R_E + H_ION) ** 2))
    ipp = u + s * d
    phi = math.asin(ipp[2] / np.linalg.norm(ipp))
    lam = math.atan2(ipp[1], ipp[0])
    local = (sow_bdt + math.degrees(lam) / 15.0 * 3600.0) % 86400.0
    x = abs(phi) / math.pi
    amp = max(0.0, sum(a * x**i for i, a in enumerate(c.alpha)))
    per = min(max(sum(bb * x**i for i, bb in enumerate(c.beta)), 72000.0), 172800.0)
    vertical = 5e-9 + (
        amp * math.cos(2 * math.pi * (local - 50400.0) / per) if abs(local - 50400.0) < per / 4 else 0.0
    )
    # obliquity from the angle between the ray and the local vertical at the pierce point
    cos_zenith_ipp = float(d @ ipp) / np.linalg.norm(ipp)
    return C * vertical / float(cos_zenith_ipp), math.cos(lam - lon) < 0.0


def test_klobuchar_bds_matches_vector_rederivation() -> None:
    worst, n, skipped = 0.0, 0, 0
    for lat, lon, az, el, hour in itertools.product(
        (D(-60.0), D(-10.0), D(22.3), D(45.0), D(75.0)),
        (D(-120.0), D(0.0), D(114.2), D(170.0)),
        [D(a) for a in range(0, 360, 40)],
        (D(3.0), D(10.0), D(30.0), D(60.0), D(89.0)),
        (0.0, 4.0, 8.0, 12.0, 16.0, 20.0),
    ):
        sow = 86400.0 * 4 + hour * 3600.0
        ours = klobuchar_bds_m(_gpst_for_bdt_sow(sow), lat, lon, az, el, BDS_HKSC)
        theirs, over_pole = _bds_by_vectors(sow, lat, lon, az, el, BDS_HKSC)
        if over_pole:  # 75 deg N looking north at 3 deg: outside the ICD formula's validity
            skipped += 1
            continue
        worst = max(worst, abs(ours - theirs))
        n += 1
    print(
        f"\nklobuchar_bds_m vs vector re-derivation: {n} cases, max |diff| {worst:.2e} m ({skipped} over the pole)"
    )
    assert worst < 1e-6
    assert skipped < 30


def test_klobuchar_bds_uses_bdt() -> None:
    """Same instant written in GPST: the 14 s offset is applied inside (not a 14 s shift)."""
    lat, lon, az, el = D(22.3), D(114.2), D(120.0), D(30.0)
    sow = 86400.0 * 2 + 20000.0
    expected, _ = _bds_by_vectors(sow, lat, lon, az, el, BDS_HKSC)
    assert klobuchar_bds_m(_gpst_for_bdt_sow(sow), lat, lon, az, el, BDS_HKSC) == pytest.approx(
        expected, abs=1e-9
    )
    assert klobuchar_bds_m(GpsTime(2161, sow), lat, lon, az, el, BDS_HKSC) != pytest.approx(
        expected, abs=1e-6
    )


# --- model selection --------------------------------------------------------------------------


def test_iono_delay_m_picks_model_and_falls_back(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    monkeypatch.setattr(atmosphere, "_warned", set())
    t, lat, lon, az, el = GpsTime(2161, 280000.0), D(22.3), D(114.2), D(80.0), D(40.0)
    both = NavData(iono={"G": GPS_HKSC, "C": BDS_HKSC})
    gps_only = NavData(iono={"G": GPS_HKSC})
    zeros = IonoCoefficients((0.0,) * 4, (0.0,) * 4)  # type: ignore[arg-type]
    gps = klobuchar_gps_m(t, lat, lon, az, el, GPS_HKSC)
    assert iono_delay_m("G", t, lat, lon, az, el, both) == gps
    assert iono_delay_m("C", t, lat, lon, az, el, both) == klobuchar_bds_m(t, lat, lon, az, el, BDS_HKSC)
    assert iono_delay_m("C", t, lat, lon, az, el, gps_only) == pytest.approx(gps * GPS_L1_TO_BDS_B1I)
    assert pytest.approx((1575.42 / 1561.098) ** 2) == GPS_L1_TO_BDS_B1I
    assert iono_delay_m("C", t, lat, lon, az, el, NavData(iono={"G": GPS_HKSC, "C": zeros})) == pytest.approx(
        gps * GPS_L1_TO_BDS_B1I
    )
    with caplog.at_level(logging.WARNING, logger="coplane.gnss.atmosphere"):
        assert iono_delay_m("G", t, lat, lon, az, el, NavData()) == 0.0
        assert iono_delay_m("G", t, lat, lon, az, el, NavData(iono={"G": zeros})) == 0.0
    assert sum("no broadcast ionosphere" in r.message for r in caplog.records) == 1  # once per system


# --- Saastamoinen vs RTKLIB tropmodel ---------------------------------------------------------


def test_saastamoinen_matches_rtklib_tropmodel() -> None:
    t = GpsTime(2320, 30000.0)
    worst, n = 0.0, 0
    for lat, h, el, humi in itertools.product(
        [D(v) for v in (-85.0, -35.0, 0.0, 22.3, 35.1, 70.0)],
        (-150.0, -50.0, 0.0, 4.9, 104.9, 1500.0, 8848.0, 10500.0),
        [D(v) for v in (-1.0, 0.0, 2.0, 5.0, 10.0, 30.0, 60.0, 90.0)],
        (0.0, 0.5, 0.7, 1.0),
    ):
        ours = saastamoinen_m(lat, h, el, humi)
        theirs = ref.tropmodel(t, lat, 2.0, h, 0.3, el, humi)
        worst = max(worst, abs(ours - theirs))
        n += 1
    print(f"\nsaastamoinen_m vs RTKLIB tropmodel: {n} cases, max |diff| {worst:.2e} m")
    assert worst < 1e-6


def test_saastamoinen_plausible_values() -> None:
    zenith = saastamoinen_m(D(35.0), 0.0, math.pi / 2)
    assert 2.3 < zenith < 2.5  # ~2.4 m at sea level
    assert saastamoinen_m(D(35.0), 0.0, D(10.0)) == pytest.approx(zenith / math.sin(D(10.0)), rel=1e-12)
    assert saastamoinen_m(D(35.0), 2000.0, math.pi / 2) < zenith


# --- arrays: one call per system in geometry.broadcast_delays ---------------------------------


def test_models_on_arrays_match_the_float_calls() -> None:
    """Each model evaluates an epoch's satellites at once; every element must be what the float
    call gives (numpy's SIMD asin/pow may differ from libm in the last bit), 0 at/below horizon."""
    rng = np.random.default_rng(16)
    az = rng.uniform(0.0, 2.0 * math.pi, 300)
    el = np.concatenate([[0.0, -0.0, -1e-9, 1e-9, math.pi / 2, -0.3], rng.uniform(-0.4, math.pi / 2, 294)])
    worst = 0.0
    for (lat, lon), hour in itertools.product(
        ((D(22.3), D(114.2)), (D(-60.0), D(-70.0)), (D(78.0), D(15.0))), (2.0, 13.0, 14.0, 20.0)
    ):
        t = _gpst_for_bdt_sow(86400.0 * 3 + hour * 3600.0)
        gps = functools.partial(klobuchar_gps_m, t, lat, lon, coeffs=GPS_HKSC)
        bds = functools.partial(klobuchar_bds_m, t, lat, lon, coeffs=BDS_HKSC)
        pairs = [
            (f(az, el), [f(a, e) for a, e in zip(az.tolist(), el.tolist(), strict=True)]) for f in (gps, bds)
        ]
        pairs.append((saastamoinen_m(lat, 120.0, el), [saastamoinen_m(lat, 120.0, e) for e in el.tolist()]))
        for vec, one in pairs:
            assert isinstance(vec, np.ndarray) and vec.shape == el.shape
            assert np.all(vec[el <= 0.0] == 0.0) and np.all(vec[el > 0.0] > 0.0)
            worst = max(worst, float(np.max(np.abs(vec - np.array(one)))))
        few = gps(az[:5], el[:5])  # below VECTORISE_FROM: one by one, as the float calls
        assert isinstance(few, np.ndarray) and list(few) == pairs[0][1][:5]
    assert worst < 1e-12
    high = saastamoinen_m(D(22.3), 1.2e4, el)
    assert high.shape == el.shape and not high.any()
    assert not iono_delay_m("R", GpsTime(2161, 0.0), 0.4, 2.0, az, el, NavData()).any()


@pytest.mark.parametrize("iono_model", ["broadcast", "rtklib"])
@pytest.mark.parametrize("iono_keys", ["GC", "G", "C", ""])
@pytest.mark.parametrize("copies", [1, 4])  # model groups below and above VECTORISE_FROM
def test_broadcast_delays_matches_per_satellite_calls(
    iono_model: Literal["broadcast", "rtklib"], iono_keys: str, copies: int
) -> None:
    """Satellites grouped by system give each one what its own float call gives."""
    rng = np.random.default_rng(7)
    systems = list("GGCEGCJCRGCC") * copies
    n = len(systems)
    el, az = rng.uniform(-0.2, math.pi / 2, n), rng.uniform(0.0, 2.0 * math.pi, n)
    view = SkyView(np.zeros(3), D(22.3), D(114.2), 30.0, np.zeros(n), np.zeros((n, 3)), el, az)
    nav = NavData(iono={k: {"G": GPS_HKSC, "C": BDS_HKSC}[k] for k in iono_keys})
    t = GpsTime(2161, 280000.0)
    iono, tropo = broadcast_delays(systems, t, view, nav, iono_model=iono_model)
    for i, s in enumerate(systems):
        a, e = float(az[i]), float(el[i])
        if iono_model == "rtklib" and s == "C" and "G" in nav.iono:
            expected = klobuchar_gps_m(t, view.lat, view.lon, a, e, GPS_HKSC) * GPS_L1_TO_BDS_B1I
        else:
            expected = iono_delay_m(s, t, view.lat, view.lon, a, e, nav)
        assert iono[i] == pytest.approx(expected, rel=0.0, abs=1e-12)
        assert tropo[i] == pytest.approx(saastamoinen_m(view.lat, view.h, e), rel=0.0, abs=1e-12)
    off = broadcast_delays(systems, t, view, nav, iono=False, tropo=False)
    assert not off[0].any() and not off[1].any()


def test_repeated_views_and_delays_are_the_same_read_only_arrays() -> None:
    """An agent's epoch asks for the view and delays at its SPP fix several times: a repeat gets
    the kept ones, which nobody can change, and anything else that differs is computed anew."""
    from coplane.geo import geodetic_to_ecef
    from coplane.gnss.geometry import sky_view

    rx = geodetic_to_ecef(D(22.3), D(114.2), 30.0)
    sats = np.array([[-2.0e7, 1.0e7, 1.2e7], [-1.0e7, 1.8e7, 1.5e7], [-2.2e7, 1.4e6, 1.1e7]])
    view = sky_view(sats, rx)
    assert sky_view(sats.copy(), rx.copy()) is view
    with pytest.raises(ValueError, match="read-only"):
        view.el_rad[0] = 0.0
    assert sky_view(sats, rx + np.array([1.0, 0.0, 0.0])) is not view
    systems, t = ["G", "C", "G"], GpsTime(2161, 280000.0)
    gps_only, both = NavData(iono={"G": GPS_HKSC}), NavData(iono={"G": GPS_HKSC, "C": BDS_HKSC})
    view = sky_view(sats, rx)
    first = broadcast_delays(systems, t, view, gps_only)
    again = broadcast_delays(systems, t, view, gps_only)
    assert again[0] is first[0] and again[1] is first[1]
    with pytest.raises(ValueError, match="read-only"):
        first[0][0] = 0.0
    other = broadcast_delays(systems, t, view, both)  # BeiDou's own coefficients now
    assert other[0] is not first[0] and other[0][1] != first[0][1] and other[0][0] == first[0][0]
    assert broadcast_delays(systems, t + 1.0, view, gps_only)[0][0] != first[0][0]


def test_broadcast_delays_never_hand_one_view_s_delays_to_another() -> None:
    """Two vehicles of one epoch in one process (`coplane eval`, the load generator): the second
    view can land at the address of a first one freed in between. The cache keyed on the view's
    id then returned the first vehicle's delays (centimetres off, and a different run's allocator
    gave different positions: docs/results.md's standalone gamp-cp moved between regenerations).
    Whatever the allocator does, each view gets the delays of its own position (the id-keyed
    cache failed this within the first few of these loops, 4 cm off)."""
    from coplane.gnss.geometry import sky_view

    nav = NavData(iono={"G": GPS_HKSC})
    t = GpsTime(2160, 200000.0)
    systems = ["G"] * 6
    rng = np.random.default_rng(3)
    sats = np.array([0.0, 0.0, 6.4e6]) + rng.normal(0.0, 1.2e7, (6, 3)) + np.array([-2.4e7, 1.2e7, 1.2e7])
    base = np.array([-2418077.0, 5386069.0, 2405174.0])
    for k in range(200):
        a = sky_view(sats, base + k)
        broadcast_delays(systems, t, a, nav)
        del a
        sky_view(sats, base - 1e5)  # another view replaces the freed one in the view cache
        b = sky_view(sats, base + np.array([2e4, -3e4, 1e4]) + k)  # 40 km away: other delays
        got = broadcast_delays(systems, t, b, nav)[0]
        want = [iono_delay_m("G", t, b.lat, b.lon, b.az_rad[i], b.el_rad[i], nav) for i in range(6)]
        assert got == pytest.approx(want, rel=1e-12, abs=1e-12)
