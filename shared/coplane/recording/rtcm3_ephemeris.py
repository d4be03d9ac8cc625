"""RTCM 3 broadcast ephemerides: 1019 (GPS) and 1042 (BeiDou) built from and decoded into the
model's Ephemeris. Field tables (data field, LSB) come from pyrtcm; semicircle fields are scaled by
pi here. The ICD LSBs are those RTCM copies, so real broadcast values round-trip to a RINEX
navigation file's printed digits (recording/rtcm3.py's docstring has the details).
"""

from __future__ import annotations

import math
from typing import Any

from pyrtcm.rtcmtypes_core import RTCM_DATA_FIELDS

from coplane.gtime import GpsTime, bdt_to_gpst, gpst_to_bdt
from coplane.recording.broadcast import MAX_TOW_JUMP_S, nearest_week, resolve_week, ura_index, ura_value
from coplane.recording.model import Ephemeris
from coplane.recording.rtcm_encode import build_frame

EPHEMERIS = {"G": "1019", "C": "1042"}


_SC = math.pi
# model attribute -> (data field, extra factor): value = raw * LSB(pyrtcm) * factor
_GPS_FIELDS: dict[str, tuple[str, float]] = {
    "idot": ("DF079", _SC), "iode": ("DF071", 1.0), "af2": ("DF082", 1.0), "af1": ("DF083", 1.0),
    "af0": ("DF084", 1.0), "iodc": ("DF085", 1.0), "crs": ("DF086", 1.0), "delta_n": ("DF087", _SC),
    "m0": ("DF088", _SC), "cuc": ("DF089", 1.0), "e": ("DF090", 1.0), "cus": ("DF091", 1.0),
    "sqrt_a": ("DF092", 1.0), "cic": ("DF094", 1.0), "omega0": ("DF095", _SC), "cis": ("DF096", 1.0),
    "i0": ("DF097", _SC), "crc": ("DF098", 1.0), "omega": ("DF099", _SC), "omega_dot": ("DF100", _SC),
    "tgd": ("DF101", 1.0),
}  # fmt: skip
_BDS_FIELDS: dict[str, tuple[str, float]] = {
    "idot": ("DF491", _SC), "iode": ("DF492", 1.0), "af2": ("DF494", 1.0), "af1": ("DF495", 1.0),
    "af0": ("DF496", 1.0), "iodc": ("DF497", 1.0), "crs": ("DF498", 1.0), "delta_n": ("DF499", _SC),
    "m0": ("DF500", _SC), "cuc": ("DF501", 1.0), "e": ("DF502", 1.0), "cus": ("DF503", 1.0),
    "sqrt_a": ("DF504", 1.0), "cic": ("DF506", 1.0), "omega0": ("DF507", _SC), "cis": ("DF508", 1.0),
    "i0": ("DF509", _SC), "crc": ("DF510", 1.0), "omega": ("DF511", _SC), "omega_dot": ("DF512", _SC),
    "tgd": ("DF513", 1e-9), "tgd2": ("DF514", 1e-9),  # 0.1 ns LSB in pyrtcm's table, in ns
}  # fmt: skip


def field_lsb(df: str) -> float:
    """The LSB pyrtcm gives a data field (1 for integer fields)."""
    res = RTCM_DATA_FIELDS[df][2]
    return 1.0 if res in (0, 1) else float(res)


def ephemeris_lsb(sys: str) -> dict[str, float]:
    """LSB of each ephemeris attribute in model units (rad, s, m, ...) as 1019/1042 carry it."""
    table = _GPS_FIELDS if sys == "G" else _BDS_FIELDS
    return {a: field_lsb(df) * f for a, (df, f) in table.items()}


def ephemeris_frame(e: Ephemeris) -> bytes:
    """1019 (GPS) or 1042 (BeiDou) for one ephemeris; FieldRangeError if a value does not fit."""
    sys = e.system
    if sys not in EPHEMERIS:
        raise ValueError(f"{e.sat}: only GPS and BeiDou ephemerides have an RTCM message here")
    table = _GPS_FIELDS if sys == "G" else _BDS_FIELDS
    v: dict[str, int] = {df: round(getattr(e, a) / (field_lsb(df) * f)) for a, (df, f) in table.items()}
    prn = int(e.sat[1:])
    if sys == "G":
        v |= {
            "DF009": prn, "DF076": e.week % 1024, "DF077": ura_index(e.sva), "DF078": 0,
            "DF081": round(e.toc.tow / 16), "DF093": round(e.toe.tow / 16), "DF102": e.health,
            "DF103": 0, "DF137": 0 if e.fit_hours <= 4.0 else 1,
        }  # fmt: skip
    else:
        v |= {
            "DF488": prn, "DF489": e.week, "DF490": ura_index(e.sva),
            "DF493": round(gpst_to_bdt(e.toc)[1] / 8), "DF505": round(gpst_to_bdt(e.toe)[1] / 8),
            "DF515": e.health,
        }  # fmt: skip
    return build_frame(EPHEMERIS[sys], v)


def _adjust(t: GpsTime, ref: GpsTime) -> GpsTime:
    """t moved by whole weeks to within half a week of ref (toc/toe around a week boundary)."""
    return nearest_week(t.tow, ref) if abs(t - ref) > MAX_TOW_JUMP_S else t


def decode_ephemeris(msg: Any, reference: GpsTime) -> Ephemeris:
    """Ephemeris from a parsed 1019 / 1042 (1019's week resolved against `reference`)."""
    sys = "G" if msg.identity == "1019" else "C"
    table = _GPS_FIELDS if sys == "G" else _BDS_FIELDS
    vals = {a: float(getattr(msg, df)) * f for a, (df, f) in table.items()}
    if sys == "G":
        sat = f"G{int(msg.DF009):02d}"
        week = resolve_week(int(msg.DF076), 10, reference.week)
        toe = GpsTime(week, float(msg.DF093))
        toc = _adjust(GpsTime(week, float(msg.DF081)), toe)
        sva, health = ura_value(int(msg.DF077)), int(msg.DF102)
        fit = 4.0 if int(msg.DF137) == 0 else 6.0
    else:
        sat = f"C{int(msg.DF488):02d}"
        week = int(msg.DF489)
        toe = bdt_to_gpst(week, float(msg.DF505))
        toc = _adjust(bdt_to_gpst(week, float(msg.DF493)), toe)
        sva, health, fit = ura_value(int(msg.DF490)), int(msg.DF515), 0.0
    vals["iode"], vals["iodc"] = float(round(vals["iode"])), float(round(vals["iodc"]))
    return Ephemeris(sat=sat, toc=toc, toe=toe, week=week, sva=sva, health=health, fit_hours=fit, **vals)
