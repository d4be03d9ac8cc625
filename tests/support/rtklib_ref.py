"""RTKLIB (pyrtklib 0.2.7 = RTKLIB 2.4.3 b34) as a test-only reference.

Tests compare our models against RTKLIB through these thin wrappers, so the pyrtklib calling
conventions (fixed-size C arrays, `gtime_t`, satellite numbers, SNR units) live in one place:

* loading:     `load_obs`, `load_nav`, `split_epochs` (RINEX -> RTKLIB `obs_t`/`nav_t`, per epoch)
* conversion:  `gtime_to_gpst`, `gpst_to_gtime`, `sat_id`, `sat_no`, `eph_to_ephemeris`,
               `navdata_from_rtklib` (RTKLIB `eph_t` -> our `Ephemeris`; keeps orbit maths tests
               independent of our RINEX parser, which is checked against RTKLIB separately)
* reference:   `satposs`, `eph2pos`, `eph2clk` (with `ephemeris_to_eph_t`), `pntpos`,
               `ionmodel`, `tropmodel`, `geodist`
* observables: `epoch_pseudoranges` (the code `satposs` itself uses), `epoch_cn0`

Only tests import this module; the library never depends on pyrtklib.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyrtklib as rtk

from coplane.gtime import GpsTime, gpst_to_bdt
from coplane.recording.model import Ephemeris, IonoCoefficients, NavData

# RTKLIB stores accuracy as a URA index (rinex.c uraindex); this is its metres table.
_URA_M = (2.4, 3.4, 4.85, 6.85, 9.65, 13.65, 24.0, 48.0, 96.0, 192.0, 384.0, 768.0, 1536.0, 3072.0, 6144.0)
_URA_BEYOND_TABLE_M = 9999.0  # index 15: "worse than 6144 m"
_SYSTEMS = {rtk.SYS_GPS: "G", rtk.SYS_CMP: "C"}  # the systems we convert ephemerides for


# --- time and satellite ids -------------------------------------------------------------------


def gtime_to_gpst(t: rtk.gtime_t) -> GpsTime:
    week = rtk.Arr1Dint(1)
    tow = rtk.time2gpst(t, week)
    return GpsTime(int(week[0]), float(tow))


def gpst_to_gtime(t: GpsTime) -> rtk.gtime_t:
    return rtk.gpst2time(t.week, t.tow)


def sat_id(satno: int) -> str:
    """RTKLIB satellite number -> "G05"/"C59" (RINEX 3 id)."""
    buf = rtk.Arr1Dchar(8)
    rtk.satno2id(satno, buf)
    return str(buf[0])  # pyrtklib returns the NUL-terminated string starting at that index


def sat_no(sat: str) -> int:
    return int(rtk.satid2no(sat))


# --- loading ----------------------------------------------------------------------------------


def load_obs(path: str | Path, rcv: int = 1) -> rtk.obs_t:
    """Read one RINEX observation file (RTKLIB `readrnx`), sorted by time and receiver."""
    obs, nav, sta = rtk.obs_t(), rtk.nav_t(), rtk.sta_t()
    if rtk.readrnx(str(path), rcv, "", obs, nav, sta) != 1:
        raise OSError(f"RTKLIB readrnx failed on {path}")
    rtk.sortobs(obs)
    return obs


def load_nav(paths: str | Path | Iterable[str | Path]) -> rtk.nav_t:
    """Read and merge RINEX navigation files (RTKLIB `readrnx` + `uniqnav`)."""
    items = [paths] if isinstance(paths, str | Path) else list(paths)
    obs, nav, sta = rtk.obs_t(), rtk.nav_t(), rtk.sta_t()
    for p in items:
        if rtk.readrnx(str(p), 0, "", obs, nav, sta) != 1:
            raise OSError(f"RTKLIB readrnx failed on {p}")
    rtk.uniqnav(nav)
    return nav


@dataclass
class RtkEpoch:
    """One receiver epoch of an RTKLIB `obs_t`: a contiguous copy of its `obsd_t` records."""

    time: GpsTime
    gtime: rtk.gtime_t
    data: rtk.Arr1Dobsd_t
    n: int

    def records(self) -> list[rtk.obsd_t]:
        return [self.data[i] for i in range(self.n)]


def split_epochs(obs: rtk.obs_t, tolerance_s: float = 0.05) -> list[RtkEpoch]:
    """Group a sorted `obs_t` into epochs (records whose times differ by < `tolerance_s`)."""
    out: list[RtkEpoch] = []
    i = 0
    while i < obs.n:
        t0 = obs.data[i].time
        n = 1
        while i + n < obs.n and abs(rtk.timediff(obs.data[i + n].time, t0)) < tolerance_s:
            n += 1
        out.append(RtkEpoch(gtime_to_gpst(t0), t0, obs.data[i : i + n], n))
        i += n
    return out


# --- observables as RTKLIB sees them ----------------------------------------------------------


def _first_code(d: rtk.obsd_t) -> float:
    p = d.P
    for j in range(rtk.NFREQ):
        if p[j] != 0.0:
            return float(p[j])
    return 0.0


def epoch_pseudoranges(epoch: RtkEpoch) -> dict[str, float]:
    """The pseudorange `satposs` uses per satellite: the first non-zero code (index 0 is L1 C/A
    for GPS and B1I for BeiDou in RTKLIB's frequency order)."""
    out: dict[str, float] = {}
    for d in epoch.records():
        p = _first_code(d)
        if p != 0.0:
            out[sat_id(d.sat)] = p
    return out


def epoch_cn0(epoch: RtkEpoch, freq_index: int = 0) -> dict[str, float]:
    """C/N0 in dB-Hz on one frequency slot (RTKLIB stores SNR in units of SNR_UNIT)."""
    return {
        sat_id(d.sat): float(d.SNR[freq_index]) * rtk.SNR_UNIT
        for d in epoch.records()
        if d.SNR[freq_index] > 0
    }


# --- reference computations -------------------------------------------------------------------


@dataclass(frozen=True)
class RefSatState:
    """One row of RTKLIB `satposs` output (broadcast ephemeris, EPHOPT_BRDC)."""

    sat: str
    pos: np.ndarray
    vel: np.ndarray
    clock_s: float
    drift_s_per_s: float
    variance_m2: float
    health: int


def satposs(epoch: RtkEpoch, nav: rtk.nav_t) -> dict[str, RefSatState]:
    """RTKLIB `satposs` for one epoch; satellites RTKLIB could not compute are left out."""
    n = epoch.n
    rs, dts = rtk.Arr1Ddouble(6 * n), rtk.Arr1Ddouble(2 * n)
    var, svh = rtk.Arr1Ddouble(n), rtk.Arr1Dint(n)
    rtk.satposs(epoch.gtime, epoch.data.ptr, n, nav, rtk.EPHOPT_BRDC, rs, dts, var, svh)
    out: dict[str, RefSatState] = {}
    for k, d in enumerate(epoch.records()):
        pos = np.array([rs[6 * k + j] for j in range(3)])
        if not np.any(pos):
            continue
        out[sat_id(d.sat)] = RefSatState(
            sat=sat_id(d.sat),
            pos=pos,
            vel=np.array([rs[6 * k + 3 + j] for j in range(3)]),
            clock_s=float(dts[2 * k]),
            drift_s_per_s=float(dts[2 * k + 1]),
            variance_m2=float(var[k]),
            health=int(svh[k]),
        )
    return out


@dataclass(frozen=True)
class RefSolution:
    """RTKLIB `pntpos` output for one epoch (single point positioning)."""

    ok: bool
    message: str
    pos: np.ndarray  # ECEF, m
    vel: np.ndarray  # ECEF, m/s (RTKLIB estvel from Doppler; zeros when it had none)
    dtr_s: np.ndarray  # receiver clock (GPS) then system offsets, s, as sol_t.dtr
    cov_pos: np.ndarray  # 3x3 ECEF covariance from the weighted least squares (float32 in RTKLIB)
    azel: dict[str, tuple[float, float]]  # satellites used: azimuth, elevation (rad)
    residuals: dict[str, float]  # satellites used: pseudorange residual (m)


def pntpos(
    epoch: RtkEpoch,
    nav: rtk.nav_t,
    navsys: int = rtk.SYS_GPS | rtk.SYS_CMP,
    elmin_deg: float = 15.0,
    err: tuple[float, ...] = (100.0, 0.003, 0.003, 0.0, 1.0),
    raim: bool = False,
) -> RefSolution:
    """RTKLIB `pntpos` with broadcast ephemeris, Klobuchar and Saastamoinen (RTKLIB's SPP).

    A fresh `prcopt_t` is filled in (the shared `prcopt_default` is left untouched).
    """
    opt = rtk.prcopt_t()
    opt.mode, opt.navsys, opt.elmin = rtk.PMODE_SINGLE, navsys, math.radians(elmin_deg)
    opt.sateph, opt.ionoopt, opt.tropopt = rtk.EPHOPT_BRDC, rtk.IONOOPT_BRDC, rtk.TROPOPT_SAAS
    opt.maxgdop = 30.0
    for i, v in enumerate(err):
        opt.err[i] = v
    opt.posopt[4] = int(raim)
    sol, ssat = rtk.sol_t(), rtk.Arr1Dssat_t(rtk.MAXSAT)
    azel, msg = rtk.Arr1Ddouble(2 * epoch.n), rtk.Arr1Dchar(256)
    ok = bool(rtk.pntpos(epoch.data.ptr, epoch.n, nav, opt, sol, azel, ssat.ptr, msg))
    q = [float(v) for v in list(sol.qr)[:6]]  # xx yy zz xy yz zx
    cov = np.array([[q[0], q[3], q[5]], [q[3], q[1], q[4]], [q[5], q[4], q[2]]])
    used = {}
    res = {}
    for d in epoch.records():
        st = ssat[d.sat - 1]
        if st.vs:
            used[sat_id(d.sat)] = (float(st.azel[0]), float(st.azel[1]))
            res[sat_id(d.sat)] = float(st.resp[0])
    return RefSolution(
        ok=ok,
        message=str(msg[0]),
        pos=np.array([sol.rr[i] for i in range(3)]),
        vel=np.array([sol.rr[i] for i in range(3, 6)]),
        dtr_s=np.array([sol.dtr[i] for i in range(6)]),
        cov_pos=cov,
        azel=used,
        residuals=res,
    )


def _arr(values: Iterable[float]) -> rtk.Arr1Ddouble:
    vals = list(values)
    a = rtk.Arr1Ddouble(len(vals))
    for i, v in enumerate(vals):
        a[i] = float(v)
    return a


def ionmodel(
    t: GpsTime,
    coeffs: IonoCoefficients,
    lat: float,
    lon: float,
    h: float,
    az: float,
    el: float,
) -> float:
    """RTKLIB `ionmodel` (GPS Klobuchar, L1 delay in m). Angles in radians.

    Note RTKLIB substitutes its built-in 2004 coefficients when all eight are zero.
    """
    ion = _arr([*coeffs.alpha, *coeffs.beta])
    return float(rtk.ionmodel(gpst_to_gtime(t), ion, _arr([lat, lon, h]), _arr([az, el])))


def tropmodel(t: GpsTime, lat: float, lon: float, h: float, az: float, el: float, humi: float) -> float:
    """RTKLIB `tropmodel` (Saastamoinen, standard atmosphere), metres."""
    return float(rtk.tropmodel(gpst_to_gtime(t), _arr([lat, lon, h]), _arr([az, el]), humi))


def geodist(sat_pos: np.ndarray, rx_pos: np.ndarray) -> tuple[float, np.ndarray]:
    """RTKLIB `geodist`: Sagnac-corrected range and receiver->satellite unit vector."""
    e = rtk.Arr1Ddouble(3)
    r = float(rtk.geodist(_arr(sat_pos), _arr(rx_pos), e))
    return r, np.array([e[0], e[1], e[2]])


# --- ephemeris conversion ---------------------------------------------------------------------


def eph_to_ephemeris(eph: rtk.eph_t) -> Ephemeris:
    """RTKLIB `eph_t` -> our `Ephemeris` (GPST times; BeiDou AODE/TGD1 conventions).

    RTKLIB keeps toc/toe/ttr in GPST already (it converts BeiDou from BDT on reading), stores A
    instead of sqrt(A) and the URA as an index, which is mapped back to the table value.
    """
    sat = sat_id(eph.sat)
    ttr = gtime_to_gpst(eph.ttr)
    ttr_sow = gpst_to_bdt(ttr)[1] if sat[0] == "C" else ttr.tow
    tgd = eph.tgd
    return Ephemeris(
        sat=sat,
        toc=gtime_to_gpst(eph.toc),
        af0=eph.f0,
        af1=eph.f1,
        af2=eph.f2,
        iode=float(eph.iode),
        crs=eph.crs,
        delta_n=eph.deln,
        m0=eph.M0,
        cuc=eph.cuc,
        e=eph.e,
        cus=eph.cus,
        sqrt_a=math.sqrt(eph.A),
        toe=gtime_to_gpst(eph.toe),
        cic=eph.cic,
        omega0=eph.OMG0,
        cis=eph.cis,
        i0=eph.i0,
        crc=eph.crc,
        omega=eph.omg,
        omega_dot=eph.OMGd,
        idot=eph.idot,
        week=int(eph.week),
        sva=_URA_M[eph.sva] if 0 <= eph.sva < len(_URA_M) else _URA_BEYOND_TABLE_M,
        health=int(eph.svh),
        tgd=float(tgd[0]),
        tgd2=float(tgd[1]),
        iodc=float(eph.iodc),
        ttr=ttr_sow,
        fit_hours=float(eph.fit),
    )


def ephemeris_to_eph_t(eph: Ephemeris) -> rtk.eph_t:
    """Our `Ephemeris` -> RTKLIB `eph_t` (inverse of `eph_to_ephemeris`), to run RTKLIB's own
    `eph2pos`/`eph2clk` on hand-made or perturbed records."""
    e = rtk.eph_t()
    e.sat = sat_no(eph.sat)
    e.toc, e.toe = gpst_to_gtime(eph.toc), gpst_to_gtime(eph.toe)
    e.toes = gpst_to_bdt(eph.toe)[1] if eph.system == "C" else eph.toe.tow
    e.f0, e.f1, e.f2 = eph.af0, eph.af1, eph.af2
    e.iode, e.iodc = int(eph.iode), int(eph.iodc)
    e.crs, e.crc, e.cus, e.cuc, e.cis, e.cic = eph.crs, eph.crc, eph.cus, eph.cuc, eph.cis, eph.cic
    e.deln, e.M0, e.e, e.A = eph.delta_n, eph.m0, eph.e, eph.sqrt_a**2
    e.OMG0, e.i0, e.omg, e.OMGd, e.idot = eph.omega0, eph.i0, eph.omega, eph.omega_dot, eph.idot
    e.week, e.svh, e.fit = eph.week, eph.health, eph.fit_hours
    e.sva = next((i for i, v in enumerate(_URA_M) if v >= eph.sva), len(_URA_M))
    e.tgd[0], e.tgd[1] = eph.tgd, eph.tgd2
    return e


def eph2clk(t: GpsTime, eph: Ephemeris) -> float:
    """RTKLIB `eph2clk`: clock polynomial at satellite-clock time (no relativity, no TGD)."""
    return float(rtk.eph2clk(gpst_to_gtime(t), ephemeris_to_eph_t(eph)))


def eph2pos(t: GpsTime, eph: Ephemeris) -> tuple[np.ndarray, float, float]:
    """RTKLIB `eph2pos`: ECEF position, clock (with relativity) and variance at GPST `t`."""
    rs, dts, var = rtk.Arr1Ddouble(3), rtk.Arr1Ddouble(1), rtk.Arr1Ddouble(1)
    rtk.eph2pos(gpst_to_gtime(t), ephemeris_to_eph_t(eph), rs, dts, var)
    return np.array([rs[0], rs[1], rs[2]]), float(dts[0]), float(var[0])


def _iono(values: rtk.Arr1Ddouble) -> IonoCoefficients | None:
    v = [float(values[i]) for i in range(8)]
    if not any(v):
        return None
    return IonoCoefficients(alpha=(v[0], v[1], v[2], v[3]), beta=(v[4], v[5], v[6], v[7]))


def navdata_from_rtklib(nav: rtk.nav_t) -> NavData:
    """All GPS and BeiDou ephemerides plus the GPS/BDS Klobuchar sets of an RTKLIB `nav_t`."""
    out = NavData()
    for i in range(nav.n):
        e = nav.eph[i]
        if rtk.satsys(e.sat, rtk.Arr1Dint(1)) in _SYSTEMS:
            out.add(eph_to_ephemeris(e))
    for key, values in (("G", nav.ion_gps), ("C", nav.ion_cmp)):
        coeffs = _iono(values)
        if coeffs is not None:
            out.iono[key] = coeffs
    return out
