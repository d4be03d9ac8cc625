"""GPS LNAV and BeiDou D1/D2 broadcast navigation as u-blox RXM-SFRBX, written and read back.

A u-blox receiver passes each navigation subframe it demodulates to the host as RXM-SFRBX:
ten 30-bit words (24 data bits + 6 parity) in the low bits of ten 32-bit `dwrd`, polarity
resolved. This module re-encodes a broadcast `Ephemeris` as LNAV subframes 1-3, and the GPS
Klobuchar coefficients as subframe 4 page 18 (SV id 56), with IS-GPS-200 scale factors
(Table 20-III, 20-VI; angles in semicircles), and decodes them back. Real broadcast values sit on
those grids, so a RINEX navigation record comes back to its printed 12 digits.

Layout: the 24 data bits of the ten words, concatenated, form one 240-bit stream in which every
LNAV field is contiguous (a 32-bit M0 is its 8 MSBs at the end of word 4 and 24 LSBs in word 5),
so each subframe is one ordered table of (field, bits) below. Parity bits follow IS-GPS-200
20.3.5.2 (D29*, D30* from the previous word; the parity-solving bits t are left 0, so words 2
and 10 do not end in 00 as a satellite's do); the reader checks them, and a UBX checksum covers
the frame anyway.

BeiDou D1 (MEO/IGSO) and D2 (GEO) subframes are in recording/sfrbx_bds.py.

Not carried: the HOW time gives `ttr` to 6 s; URA and the fit interval are indices (sva comes back
as the upper bound of its URA bin, RTKLIB's convention; fit flag 0 -> 4 h, 1 -> 6 h).
The 10-bit week (WN) is resolved against `reference` (default: today), like RTCM 1019.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pyubx2 import GET, UBXMessage, UBXReader

from coplane.gtime import GpsTime
from coplane.recording import sfrbx_bds as bds
from coplane.recording.broadcast import URA_TABLE_M, nearest_week, resolve_week, today, ura_index
from coplane.recording.frames import Frame
from coplane.recording.model import Ephemeris, IonoCoefficients, NavData
from coplane.recording.problems import Problems
from coplane.recording.ubx import SFRBX_CLASS_ID, log_frames

PREAMBLE = 0x8B
_SC = math.pi


@dataclass(frozen=True, slots=True)
class F:
    """One field of the 240-bit data stream: model attribute (or "" for a constant), width,
    two's complement or not, LSB in ICD units, extra factor to model units (pi for semicircles)."""

    name: str
    bits: int
    signed: bool = False
    lsb: float = 1.0
    factor: float = 1.0


_TLM_HOW = (F("_pre", 8), F("_tlm", 14), F("_isf", 1), F("_r0", 1), F("_tow", 17), F("_alert", 1),
            F("_as", 1), F("_sfid", 3), F("_t0", 2))  # fmt: skip
SUBFRAME: dict[int, tuple[F, ...]] = {
    1: (F("_wn", 10), F("_l2", 2), F("_ura", 4), F("health", 6), F("_iodc_hi", 2), F("_l2p", 1),
        F("_r1", 23), F("_r2", 24), F("_r3", 24), F("_r4", 16), F("tgd", 8, True, 2.0**-31),
        F("_iodc_lo", 8), F("_toc", 16, False, 16.0), F("af2", 8, True, 2.0**-55),
        F("af1", 16, True, 2.0**-43), F("af0", 22, True, 2.0**-31), F("_t", 2)),
    2: (F("_iode", 8), F("crs", 16, True, 2.0**-5), F("delta_n", 16, True, 2.0**-43, _SC),
        F("m0", 32, True, 2.0**-31, _SC), F("cuc", 16, True, 2.0**-29), F("e", 32, False, 2.0**-33),
        F("cus", 16, True, 2.0**-29), F("sqrt_a", 32, False, 2.0**-19), F("_toe", 16, False, 16.0),
        F("_fit", 1), F("_aodo", 5), F("_t", 2)),
    3: (F("cic", 16, True, 2.0**-29), F("omega0", 32, True, 2.0**-31, _SC), F("cis", 16, True, 2.0**-29),
        F("i0", 32, True, 2.0**-31, _SC), F("crc", 16, True, 2.0**-5), F("omega", 32, True, 2.0**-31, _SC),
        F("omega_dot", 24, True, 2.0**-43, _SC), F("_iode", 8), F("idot", 14, True, 2.0**-43, _SC),
        F("_t", 2)),
    4: (F("_data_id", 2), F("_sv", 6), F("a0", 8, True, 2.0**-30), F("a1", 8, True, 2.0**-27),
        F("a2", 8, True, 2.0**-24), F("a3", 8, True, 2.0**-24), F("b0", 8, True, 2.0**11),
        F("b1", 8, True, 2.0**14), F("b2", 8, True, 2.0**16), F("b3", 8, True, 2.0**16),
        F("_A1", 24, True), F("_A0", 32, True), F("_tot", 8), F("_wnt", 8), F("_dtls", 8, True),
        F("_wnlsf", 8), F("_dn", 8), F("_dtlsf", 8, True), F("_r", 14), F("_t", 2)),
}  # fmt: skip
PAGE18_SV = 56
_PARITY_TAPS = (  # IS-GPS-200 Table 20-XIV: data bits (1-based) in each of D25..D30, and D29*/D30*
    (29, (1, 2, 3, 5, 6, 10, 11, 12, 13, 14, 17, 18, 20, 23)),
    (30, (2, 3, 4, 6, 7, 11, 12, 13, 14, 15, 18, 19, 21, 24)),
    (29, (1, 3, 4, 5, 7, 8, 12, 13, 14, 15, 16, 19, 20, 22)),
    (30, (2, 4, 5, 6, 8, 9, 13, 14, 15, 16, 17, 20, 21, 23)),
    (30, (1, 3, 5, 6, 7, 9, 10, 14, 15, 16, 17, 18, 21, 22, 24)),
    (29, (3, 5, 6, 8, 9, 10, 11, 13, 15, 19, 22, 23, 24)),
)


def lsb(name: str) -> float:
    """LSB of an ephemeris attribute in model units, as LNAV carries it."""
    for table in SUBFRAME.values():
        for f in table:
            if f.name == name:
                return f.lsb * f.factor
    raise KeyError(name)


def _parity(data24: int, d29: int, d30: int) -> int:
    out = 0
    for prev, taps in _PARITY_TAPS:
        bit = d29 if prev == 29 else d30
        for k in taps:
            bit ^= (data24 >> (24 - k)) & 1
        out = (out << 1) | bit
    return out


def _words(stream: int) -> list[int]:
    """240 data bits -> ten 30-bit words with parity (source bits, polarity resolved)."""
    words, d29, d30 = [], 0, 0
    for i in range(10):
        data = (stream >> (24 * (9 - i))) & 0xFFFFFF
        par = _parity(data, d29, d30)
        words.append((data << 6) | par)
        d29, d30 = (par >> 1) & 1, par & 1
    return words


def _stream(words: Sequence[int]) -> tuple[int, bool]:
    """Ten words -> (240 data bits, parity good)."""
    stream, ok, d29, d30 = 0, True, 0, 0
    for w in words:
        data, par = (w >> 6) & 0xFFFFFF, w & 0x3F
        ok = ok and _parity(data, d29, d30) == par
        stream = (stream << 24) | data
        d29, d30 = (par >> 1) & 1, par & 1
    return stream, ok


def _pack(fields: tuple[F, ...], values: dict[str, int]) -> int:
    acc, n = 0, 0
    for f in (*_TLM_HOW, *fields):
        v = values.get(f.name, 0)
        lo, hi = (-(1 << (f.bits - 1)), (1 << (f.bits - 1)) - 1) if f.signed else (0, (1 << f.bits) - 1)
        if not lo <= v <= hi:
            raise ValueError(f"LNAV field {f.name}={v} outside {lo}..{hi}")
        acc = (acc << f.bits) | (v & ((1 << f.bits) - 1))
        n += f.bits
    assert n == 240, n
    return acc


def _unpack(fields: tuple[F, ...], stream: int) -> dict[str, int]:
    out: dict[str, int] = {}
    pos = 240
    for f in (*_TLM_HOW, *fields):
        pos -= f.bits
        v = (stream >> pos) & ((1 << f.bits) - 1)
        if f.signed and v >> (f.bits - 1):
            v -= 1 << f.bits
        out[f.name] = v
    return out


def _scaled(fields: tuple[F, ...], obj: Any) -> dict[str, int]:
    return {
        f.name: round(getattr(obj, f.name) / (f.lsb * f.factor)) for f in fields if not f.name.startswith("_")
    }


def _bds_sfrbx(prn: int, sig: int, stream: int) -> UBXMessage:
    kw: dict[str, int] = {"gnssId": 3, "svId": prn, "sigId": sig, "numWords": 10, "version": 2}
    kw |= {f"dwrd_{i:02d}": w for i, w in enumerate(bds.words(stream), start=1)}
    return UBXMessage("RXM", "RXM-SFRBX", GET, **kw)


def _sfrbx(prn: int, stream: int) -> UBXMessage:
    kw: dict[str, int] = {"gnssId": 0, "svId": prn, "sigId": 0, "numWords": 10, "version": 2}
    kw |= {f"dwrd_{i:02d}": w for i, w in enumerate(_words(stream), start=1)}
    return UBXMessage("RXM", "RXM-SFRBX", GET, **kw)


def ephemeris_messages(e: Ephemeris, bds_iono: IonoCoefficients | None = None) -> list[UBXMessage]:
    """GPS LNAV subframes 1-3, BeiDou D1 subframes 1-3 or D2 pages 1, 3-10 of one ephemeris
    (ValueError if a value does not fit its field)."""
    if e.system == "C":
        prn = int(e.sat[1:])
        sig = 1 if bds.is_geo(prn) else 0
        return [_bds_sfrbx(prn, sig, st) for st in bds.streams(e, bds_iono)]
    if e.system != "G":
        raise ValueError(f"{e.sat}: only GPS and BeiDou ephemerides are written as RXM-SFRBX")
    iodc = int(e.iodc)
    frame_start = (
        math.floor(e.ttr / 30.0) * 30.0 if e.ttr > 0 else math.floor((e.toe.tow - 7200) / 30.0) * 30.0
    )
    common = {"_pre": PREAMBLE}
    values = {
        1: {"_wn": e.week % 1024, "_ura": ura_index(e.sva), "_iodc_hi": iodc >> 8, "_iodc_lo": iodc & 0xFF,
            "_toc": round(e.toc.tow / 16.0), **_scaled(SUBFRAME[1], e)},
        2: {"_iode": int(e.iode), "_toe": round(e.toe.tow / 16.0), "_fit": 0 if e.fit_hours <= 4.0 else 1,
            **_scaled(SUBFRAME[2], e)},
        3: {"_iode": int(e.iode), **_scaled(SUBFRAME[3], e)},
    }  # fmt: skip
    out = []
    for sf in (1, 2, 3):
        how = int(((frame_start + 6.0 * sf) % 604800.0) // 6.0)
        v = {**common, "_tow": how, "_sfid": sf, **values[sf]}
        out.append(_sfrbx(int(e.sat[1:]), _pack(SUBFRAME[sf], v)))
    return out


def iono_message(iono: IonoCoefficients, week: int, leap: int = 18) -> UBXMessage:
    """GPS subframe 4 page 18 (Klobuchar alpha/beta; UTC parameters zero, leap seconds set)."""
    c = {f"a{i}": x for i, x in enumerate(iono.alpha)} | {f"b{i}": x for i, x in enumerate(iono.beta)}
    fields = SUBFRAME[4]
    v = {"_pre": PREAMBLE, "_sfid": 4, "_data_id": 1, "_sv": PAGE18_SV, "_wnt": week % 256, "_wnlsf": week % 256,
         "_dtls": leap, "_dtlsf": leap, "_dn": 1}  # fmt: skip
    v |= {f.name: round(c[f.name] / f.lsb) for f in fields if not f.name.startswith("_")}
    return _sfrbx(1, _pack(fields, v))


def write_sfrbx_nav(path: str | Path, nav: NavData) -> list[str]:
    """nav's GPS ephemerides (and GPS Klobuchar) as RXM-SFRBX; returns what was not written, and why."""
    skipped: list[str] = []
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("wb") as f:
        gps = [e for ephs in nav.ephemerides.values() for e in ephs if e.system == "G"]
        if "G" in nav.iono and gps:
            f.write(iono_message(nav.iono["G"], gps[0].week).serialize())
        for ephs in nav.ephemerides.values():
            for e in ephs:
                try:
                    for m in ephemeris_messages(e, nav.iono.get("C")):
                        f.write(m.serialize())
                except ValueError as exc:
                    skipped.append(f"{e.sat} toe {e.toe}: {exc}")
    return skipped


def _decode(sat: str, sfs: dict[int, dict[str, int]], reference: GpsTime) -> Ephemeris:
    s1, s2 = sfs[1], sfs[2]
    week = resolve_week(s1["_wn"], 10, reference.week)
    ttr = GpsTime(week, s1["_tow"] * 6.0 - 6.0)
    toe = nearest_week(s2["_toe"] * 16.0, ttr)
    toc = nearest_week(s1["_toc"] * 16.0, toe)
    vals: dict[str, float] = {}
    for n in (1, 2, 3):
        for f in SUBFRAME[n]:
            if not f.name.startswith("_"):
                vals[f.name] = sfs[n][f.name] * f.lsb * f.factor
    vals["health"] = float(s1["health"])
    ura = s1["_ura"]
    return Ephemeris(
        sat=sat,
        toc=toc,
        toe=toe,
        week=week,
        iode=float(s2["_iode"]),
        iodc=float((s1["_iodc_hi"] << 8) | s1["_iodc_lo"]),
        sva=URA_TABLE_M[ura] if ura < len(URA_TABLE_M) else 2.0 * URA_TABLE_M[-1],
        ttr=ttr.tow,
        fit_hours=4.0 if s2["_fit"] == 0 else 6.0,
        **{k: v for k, v in vals.items() if k != "health"},
        health=int(vals["health"]),
    )


def read_sfrbx_nav(
    path: str | Path,
    problems: Problems,
    reference: GpsTime | None = None,
    frames: Iterable[Frame] | None = None,
) -> NavData:
    """GPS ephemerides and Klobuchar coefficients from the RXM-SFRBX of a UBX file.

    Subframes 1-3 of a satellite make an ephemeris when their issues of data agree (IODE of 2 and
    3 = the 8 LSBs of IODC in 1); a subframe with bad parity or no preamble is reported and unused.
    """
    path = Path(path)
    if frames is None:
        frames = log_frames(path, problems)
    dec = SfrbxDecoder(path, problems, NavData(), reference or today())
    for fr in frames:
        dec.add(fr)
    return dec.nav


class SfrbxDecoder:
    """RXM-SFRBX frames -> ephemerides and Klobuchar coefficients in `nav`, one frame at a time
    (the file reader and live receiver streams, where subframes arrive as they are broadcast)."""

    def __init__(self, path: str | Path, problems: Problems, nav: NavData, reference: GpsTime) -> None:
        self.path, self.problems, self.nav, self.reference = path, problems, nav, reference
        self.bds = _BdsCollector(path, problems, nav)
        self.pending: dict[str, dict[int, dict[str, int]]] = {}

    def add(self, fr: Frame) -> None:
        """One UBX frame (anything but RXM-SFRBX is ignored); bad subframes are counted."""
        path, problems, nav = self.path, self.problems, self.nav
        if fr.raw[2:4] != SFRBX_CLASS_ID:  # skip other messages before parsing
            return
        try:
            msg = UBXReader.parse(fr.raw)
        except Exception as exc:  # pyubx2's own errors, struct.error, ...
            problems.add(path, None, "malformed-frame", f"RXM-SFRBX does not decode: {exc}", offset=fr.offset)
            return
        if msg.gnssId == 3 and msg.numWords == 10:
            self.bds.add(msg, fr.offset)
            return
        if msg.gnssId != 0 or msg.numWords != 10:
            return  # other systems / signals: not decoded here
        stream, parity_ok = _stream([getattr(msg, f"dwrd_{i:02d}") & 0x3FFFFFFF for i in range(1, 11)])
        head = _unpack((), stream)
        sfid = head["_sfid"]
        if head["_pre"] != PREAMBLE or not parity_ok or sfid not in SUBFRAME:
            problems.add(path, None, "malformed-record", f"G{msg.svId:02d} subframe: bad preamble or parity",
                         offset=fr.offset)  # fmt: skip
            return
        vals = _unpack(SUBFRAME[sfid], stream)
        if sfid == 4:
            if vals["_sv"] == PAGE18_SV and "G" not in nav.iono:
                nav.iono["G"] = IonoCoefficients(
                    tuple(vals[f"a{i}"] * lsb(f"a{i}") for i in range(4)),  # type: ignore[arg-type]
                    tuple(vals[f"b{i}"] * lsb(f"b{i}") for i in range(4)),  # type: ignore[arg-type]
                )
            return
        sat = f"G{int(msg.svId):02d}"
        sfs = self.pending.setdefault(sat, {})
        sfs[sfid] = vals
        if all(k in sfs for k in (1, 2, 3)):
            iodc_lo = sfs[1]["_iodc_lo"]
            if sfs[2]["_iode"] == sfs[3]["_iode"] == iodc_lo:
                try:
                    nav.add(_decode(sat, sfs, self.reference))
                except ValueError as exc:
                    problems.add(path, None, "malformed-record", f"{sat}: {exc}", offset=fr.offset)
                self.pending.pop(sat)


class _BdsCollector:
    """Gathers BeiDou D1 subframes 1-3 (SOW s, s+6, s+12) or D2 pages 1, 3-10 (SOW s + 3(k-1))."""

    def __init__(self, path: str | Path, problems: Problems, nav: NavData) -> None:
        self.path, self.problems, self.nav = path, problems, nav
        self.parts: dict[str, dict[int, dict[int, dict[str, int]]]] = {}  # sat -> number -> sow -> fields

    def add(self, msg: Any, offset: int) -> None:
        sat = f"C{int(msg.svId):02d}"
        stream, ok = bds.stream_of([getattr(msg, f"dwrd_{i:02d}") & 0x3FFFFFFF for i in range(1, 11)])
        h = bds.head(stream)
        geo = bds.is_geo(int(msg.svId))
        n = h["_pnum"] if geo else h["_fra"]
        valid = (bds.D2 if geo else bds.D1).get(n) is not None and (not geo or h["_fra"] == 1)
        if h["_pre"] != bds.PREAMBLE or not ok or not valid:
            if h["_fra"] == 1 or not geo:  # D2 subframes 2-5 (almanac, ...) are not decoded, not bad
                self.problems.add(self.path, None, "malformed-record", f"{sat} subframe: bad preamble, "
                                  "parity or number", offset=offset)  # fmt: skip
            return
        kind = "D2" if geo else "D1"
        sow = h["_sow"]
        self.parts.setdefault(sat, {}).setdefault(n, {})[sow] = bds.unpack(kind, n, stream)
        last, step = (10, 3) if geo else (3, 6)
        if n != last:
            return
        numbers = (1, 3, 4, 5, 6, 7, 8, 9, 10) if geo else (1, 2, 3)
        first = sow - step * (last - 1)
        got: dict[int, dict[str, int]] = {}
        for k in numbers:
            p = self.parts[sat].get(k, {}).get(first + step * (k - 1))
            if p is None:
                return  # not all parts of this ephemeris seen yet
            got[k] = p
        if not geo and "C" not in self.nav.iono:
            ion = bds.iono_of(got[1])
            if ion is not None:
                self.nav.iono["C"] = ion
        try:
            self.nav.add(bds.decode(sat, got, first))
        except ValueError as exc:
            self.problems.add(self.path, None, "malformed-record", f"{sat}: {exc}", offset=offset)
        self.parts.pop(sat)
