"""RTKLIB (pyrtklib) as the reference RINEX parser for the recording tests.

pyrtklib exposes RTKLIB's C structs: `obs_t.data[i]` is an `obsd_t` with per-frequency arrays
`P`, `D`, `SNR` (0.001 dB-Hz units) and `code`; `nav_t.eph[i]` is an `eph_t`. Times are
`gtime_t` converted with `time2gpst`. These helpers turn them into plain Python values keyed like
ours (GpsTime rounded to 1e-7 s, satellite ids "G05"), so the tests compare values, not structs.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pyrtklib as rt
import pytest

from coplane.gtime import SECONDS_PER_WEEK, GpsTime, bdt_to_gpst, gpst_to_bdt
from coplane.recording.model import Ephemeris, NavData
from support.rtklib_ref import gtime_to_gpst, sat_id

# RTKLIB code of the selected signal per system (GPS L1 C/A, BeiDou B1I): -GL1C/-CL2I force it.
SELECTED_CODES = {"G": rt.CODE_L1C, "C": rt.CODE_L2I}
RTKLIB_OBS_OPT = "-GL1C -CL2I"


def gps_time(t: rt.gtime_t) -> GpsTime:
    """RTKLIB time as GpsTime, rounded to 0.1 us so it can key a dict against our reader's tags."""
    g = gtime_to_gpst(t)
    return GpsTime(g.week, round(g.tow, 7))


@dataclass(frozen=True)
class RefObs:
    pseudorange_m: float
    doppler_hz: float
    snr_dbhz: float


def read_obs_rtklib(path: Path) -> dict[GpsTime, dict[str, RefObs]]:
    """Per epoch, satellites of G and C with a non-zero pseudorange on the selected signal."""
    obs, nav, sta = rt.obs_t(), rt.nav_t(), rt.sta_t()
    ret = rt.readrnx(str(path), 1, RTKLIB_OBS_OPT, obs, nav, sta)
    assert ret == 1, f"RTKLIB readrnx failed on {path}"
    out: dict[GpsTime, dict[str, RefObs]] = {}
    for i in range(obs.n):
        d = obs.data[i]
        sid = sat_id(d.sat)
        t = gps_time(d.time)
        epoch = out.setdefault(t, {})
        want = SELECTED_CODES.get(sid[0])
        if want is None:
            continue
        codes = list(d.code)
        if want not in codes:
            continue
        k = codes.index(want)
        p = d.P[k]
        if p == 0.0:
            continue
        epoch[sid] = RefObs(p, float(d.D[k]), d.SNR[k] * rt.SNR_UNIT)
    return out


def read_nav_rtklib(path: Path) -> tuple[list[rt.eph_t], rt.nav_t]:
    """Every GPS/BeiDou ephemeris record RTKLIB parsed (duplicates included) and the nav_t."""
    obs, nav, sta = rt.obs_t(), rt.nav_t(), rt.sta_t()
    ret = rt.readrnx(str(path), 1, "", obs, nav, sta)
    assert ret == 1, f"RTKLIB readrnx failed on {path}"
    ephs = [nav.eph[i] for i in range(nav.n)]
    return [e for e in ephs if sat_id(e.sat)[0] in "GC"], nav


_URA_M = (2.4, 3.4, 4.85, 6.85, 9.65, 13.65, 24.0, 48.0, 96.0, 192.0, 384.0, 768.0, 1536.0, 3072.0, 6144.0)


def ura_index(metres: float) -> int:
    """RTKLIB's uraindex(): the URA index RTKLIB stores in eph_t.sva."""
    for i, v in enumerate(_URA_M):
        if v >= metres:
            return i
    return len(_URA_M)


def all_ephemerides(nav: NavData) -> dict[tuple[str, object, float], Ephemeris]:
    return {(e.sat, e.toe, e.iode): e for lst in nav.ephemerides.values() for e in lst}


def compare_nav_to_rtklib(path: Path, nav: NavData) -> int:
    """Field-by-field comparison with RTKLIB's eph_t; returns how many ephemerides were compared."""
    ref_list, rnav = read_nav_rtklib(path)
    ref = {(sat_id(r.sat), gps_time(r.toe), float(r.iode)): r for r in ref_list}
    ours = all_ephemerides(nav)
    assert set(ref) == set(ours)
    for key, r in ref.items():
        e = ours[key]
        toes = e.toe.tow if e.system == "G" else gpst_to_bdt(e.toe)[1]
        pairs = {
            "af0": (r.f0, e.af0),
            "af1": (r.f1, e.af1),
            "af2": (r.f2, e.af2),
            "crs": (r.crs, e.crs),
            "delta_n": (r.deln, e.delta_n),
            "m0": (r.M0, e.m0),
            "cuc": (r.cuc, e.cuc),
            "e": (r.e, e.e),
            "cus": (r.cus, e.cus),
            "A": (r.A, e.sqrt_a**2),
            "toes": (r.toes, toes),
            "cic": (r.cic, e.cic),
            "omega0": (r.OMG0, e.omega0),
            "cis": (r.cis, e.cis),
            "i0": (r.i0, e.i0),
            "crc": (r.crc, e.crc),
            "omega": (r.omg, e.omega),
            "omega_dot": (r.OMGd, e.omega_dot),
            "idot": (r.idot, e.idot),
            "tgd": (r.tgd[0], e.tgd),
            "tgd2": (r.tgd[1], e.tgd2),
            "iodc": (float(r.iodc), e.iodc),
            "fit": (r.fit, e.fit_hours),
        }
        for name, (want, got) in pairs.items():
            assert got == pytest.approx(want, rel=1e-12, abs=1e-300), f"{key[0]} {name}"
        assert gps_time(r.toc) == e.toc, f"{key[0]} toc"
        assert r.week == e.week and r.svh == e.health and r.sva == ura_index(e.sva), key[0]
        # RTKLIB keeps ttr as a GPST instant near toc; ours is the broadcast seconds of week (BDT
        # for BeiDou, possibly negative = previous week), relative to the record's week
        ttr = GpsTime(e.week, e.ttr) if e.system == "G" else bdt_to_gpst(e.week, e.ttr)
        ttr = ttr + SECONDS_PER_WEEK * round((e.toc - ttr) / SECONDS_PER_WEEK)
        assert abs(gps_time(r.ttr) - ttr) < 1e-6, f"{key[0]} ttr"
    for sys, arr in (("G", rnav.ion_gps), ("C", rnav.ion_cmp)):
        vals = list(arr)[:8]
        if any(vals):
            assert nav.iono[sys].alpha + nav.iono[sys].beta == pytest.approx(tuple(vals), rel=1e-12)
        else:
            assert sys not in nav.iono
    return len(ref)
