"""BeiDou B1I broadcast navigation (D1 for MEO/IGSO, D2 for GEO) as u-blox RXM-SFRBX words.

BDS-SIS-ICD-B1I: a subframe is ten 30-bit words. Word 1 is 26 information bits (preamble 11,
reserved 4, subframe id 3, SOW 8 MSBs) and 4 parity bits; words 2-10 are 22 information bits and
8 parity bits (two BCH(15,11) code words, g(x) = x^4 + x + 1; u-blox delivers them
de-interleaved, information first). As with GPS LNAV, the information bits of the ten words,
concatenated, form one 224-bit stream in which every field is contiguous, so each subframe or page
is an ordered table of (field, bits):

* D1 (C06-C58): subframes 1-3 carry the clock, ionosphere and orbit (5.2.4 of the ICD);
* D2 (GEO: C01-C05, C59-C63): subframe 1 pages 1-10, one every 3 s, carry the same parameters in
  small pieces (5.3.3); a field split over two pages is named "<attr>^" (MSB part) and
  "<attr>_" (LSB part). Page 2 (ionosphere) is not written: D1 subframe 1 carries the BeiDou
  Klobuchar coefficients, and without them coplane uses the GPS ones (gnss/geometry.py).
Scale factors (ICD table 5-8): angles in semicircles (x pi here), toc/toe 8 s, a0 2^-33 s,
a1 2^-50, a2 2^-66, TGD 0.1 ns.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from coplane.gtime import GpsTime, bdt_to_gpst, gpst_to_bdt
from coplane.recording.broadcast import URA_TABLE_M, nearest_week, ura_index
from coplane.recording.model import Ephemeris, IonoCoefficients

PREAMBLE = 0b11100010010
_SC = math.pi


@dataclass(frozen=True, slots=True)
class Full:
    """A whole ephemeris field: width, signed, LSB in model units."""

    bits: int
    signed: bool
    lsb: float


FIELDS: dict[str, Full] = {
    "health": Full(1, False, 1.0), "iodc": Full(5, False, 1.0), "urai": Full(4, False, 1.0),
    "week": Full(13, False, 1.0), "toc": Full(17, False, 8.0), "toe": Full(17, False, 8.0),
    "tgd": Full(10, True, 1e-10), "tgd2": Full(10, True, 1e-10),
    "af2": Full(11, True, 2.0**-66), "af0": Full(24, True, 2.0**-33), "af1": Full(22, True, 2.0**-50),
    "iode": Full(5, False, 1.0), "delta_n": Full(16, True, 2.0**-43 * _SC), "cuc": Full(18, True, 2.0**-31),
    "m0": Full(32, True, 2.0**-31 * _SC), "e": Full(32, False, 2.0**-33), "cus": Full(18, True, 2.0**-31),
    "crc": Full(18, True, 2.0**-6), "crs": Full(18, True, 2.0**-6), "sqrt_a": Full(32, False, 2.0**-19),
    "i0": Full(32, True, 2.0**-31 * _SC), "cic": Full(18, True, 2.0**-31),
    "omega_dot": Full(24, True, 2.0**-43 * _SC), "cis": Full(18, True, 2.0**-31),
    "idot": Full(14, True, 2.0**-43 * _SC), "omega0": Full(32, True, 2.0**-31 * _SC),
    "omega": Full(32, True, 2.0**-31 * _SC),
}  # fmt: skip

_HEAD = (("_pre", 11), ("_rev", 4), ("_fra", 3), ("_sow", 20))
D1: dict[int, tuple[tuple[str, int], ...]] = {
    1: (("health", 1), ("iodc", 5), ("urai", 4), ("week", 13), ("toc", 17), ("tgd", 10), ("tgd2", 10),
        ("ion_a0", 8), ("ion_a1", 8), ("ion_a2", 8), ("ion_a3", 8), ("ion_b0", 8), ("ion_b1", 8),
        ("ion_b2", 8), ("ion_b3", 8), ("af2", 11), ("af0", 24), ("af1", 22), ("iode", 5)),
    2: (("delta_n", 16), ("cuc", 18), ("m0", 32), ("e", 32), ("cus", 18), ("crc", 18), ("crs", 18),
        ("sqrt_a", 32), ("toe^", 2)),
    3: (("toe_", 15), ("i0", 32), ("cic", 18), ("omega_dot", 24), ("cis", 18), ("idot", 14), ("omega0", 32),
        ("omega", 32), ("_r", 1)),
}  # fmt: skip
D2: dict[int, tuple[tuple[str, int], ...]] = {  # after ("_pnum", 4)
    1: (("health", 1), ("iodc", 5), ("urai", 4), ("week", 13), ("toc", 17), ("tgd", 10), ("tgd2", 10)),
    3: (("_r", 38), ("af0", 24), ("af1^", 4)),
    4: (("af1_", 18), ("af2", 11), ("iode", 5), ("delta_n", 16), ("cuc^", 14)),
    5: (("cuc_", 4), ("m0", 32), ("cus", 18), ("e^", 10)),
    6: (("e_", 22), ("sqrt_a", 32), ("cic^", 10)),
    7: (("cic_", 8), ("cis", 18), ("toe", 17), ("i0^", 21)),
    8: (("i0_", 11), ("crc", 18), ("crs", 18), ("omega_dot^", 19)),
    9: (("omega_dot_", 5), ("omega0", 32), ("omega^", 27)),
    10: (("omega_", 5), ("idot", 14)),
}  # fmt: skip
ION_LSB = (2.0**-30, 2.0**-27, 2.0**-24, 2.0**-24, 2.0**11, 2.0**14, 2.0**16, 2.0**16)  # alpha0-3, beta0-3
_ION = ("ion_a0", "ion_a1", "ion_a2", "ion_a3", "ion_b0", "ion_b1", "ion_b2", "ion_b3")
_LOW_BITS = {"toe": 15, "af1": 18, "cuc": 4, "e": 22, "cic": 8, "i0": 11, "omega_dot": 5, "omega": 5}
STREAM_BITS = 224


def is_geo(prn: int) -> bool:
    return prn <= 5 or prn >= 59


# ---- BCH(15,11) and the words


def _bch(info11: int) -> int:
    """4 parity bits of an 11-bit information block, g(x) = x^4 + x + 1."""
    r = info11 << 4
    for k in range(14, 3, -1):
        if r >> k & 1:
            r ^= 0b10011 << (k - 4)
    return r & 0xF


def words(stream: int) -> list[int]:
    """224 information bits -> ten 30-bit words (information first, then parity)."""
    w1 = stream >> (STREAM_BITS - 26)
    out = [(w1 << 4) | _bch(w1 & 0x7FF)]
    for i in range(9):
        info = (stream >> (STREAM_BITS - 26 - 22 * (i + 1))) & 0x3FFFFF
        hi, lo = info >> 11, info & 0x7FF
        out.append((info << 8) | (_bch(hi) << 4) | _bch(lo))
    return out


def stream_of(ws: Sequence[int]) -> tuple[int, bool]:
    """Ten words -> (224 information bits, all BCH parities good)."""
    w1 = ws[0] >> 4
    ok = _bch(w1 & 0x7FF) == ws[0] & 0xF
    stream = w1
    for w in ws[1:]:
        info = (w >> 8) & 0x3FFFFF
        ok = ok and _bch(info >> 11) == (w >> 4) & 0xF and _bch(info & 0x7FF) == w & 0xF
        stream = (stream << 22) | info
    return stream, ok


# ---- fields


def _layout(kind: str, n: int) -> tuple[tuple[str, int], ...]:
    body = D1[n] if kind == "D1" else (("_pnum", 4), *D2[n])
    used = sum(b for _, b in _HEAD) + sum(b for _, b in body)
    return (*_HEAD, *body, ("_pad", STREAM_BITS - used)) if used < STREAM_BITS else (*_HEAD, *body)


def _raw_fields(e: Ephemeris) -> dict[str, int]:
    """Every piece's bit pattern for one ephemeris (ValueError if a value does not fit)."""
    toc = gpst_to_bdt(e.toc)[1]
    vals = {
        a: round(getattr(e, a) / f.lsb) for a, f in FIELDS.items() if a not in ("urai", "week", "toc", "toe")
    }
    vals |= {
        "urai": ura_index(e.sva),
        "week": e.week,
        "toc": round(toc / 8.0),
        "toe": round(gpst_to_bdt(e.toe)[1] / 8.0),
    }
    out: dict[str, int] = {}
    for a, v in vals.items():
        f = FIELDS[a]
        lo, hi = (-(1 << (f.bits - 1)), (1 << (f.bits - 1)) - 1) if f.signed else (0, (1 << f.bits) - 1)
        if not lo <= v <= hi:
            raise ValueError(f"BeiDou field {a}={v} outside {lo}..{hi}")
        u = v & ((1 << f.bits) - 1)
        out[a] = u
        if a in _LOW_BITS:
            out[a + "^"], out[a + "_"] = u >> _LOW_BITS[a], u & ((1 << _LOW_BITS[a]) - 1)
    return out


def _pack(layout: tuple[tuple[str, int], ...], values: dict[str, int]) -> int:
    acc = 0
    for name, bits in layout:
        acc = (acc << bits) | (values.get(name, 0) & ((1 << bits) - 1))
    return acc


def unpack(kind: str, n: int, stream: int) -> dict[str, int]:
    out: dict[str, int] = {}
    pos = STREAM_BITS
    for name, bits in _layout(kind, n):
        pos -= bits
        out[name] = (stream >> pos) & ((1 << bits) - 1)
    return out


def head(stream: int) -> dict[str, int]:
    """Preamble, subframe id, SOW and (for D2) the page number of any subframe."""
    h = unpack("D2", 1, stream)
    return {k: h[k] for k in ("_pre", "_fra", "_sow", "_pnum")}


def streams(e: Ephemeris, iono: IonoCoefficients | None = None) -> list[int]:
    """The information streams of one ephemeris: D1 subframes 1-3 (with the BeiDou Klobuchar
    coefficients in subframe 1 when given), or D2 subframe 1 pages 1, 3-10."""
    prn = int(e.sat[1:])
    raw = _raw_fields(e)
    if iono is not None:
        for name, coef, q in zip(_ION, (*iono.alpha, *iono.beta), ION_LSB, strict=True):
            k = round(coef / q)
            if not -128 <= k <= 127:
                raise ValueError(f"BeiDou Klobuchar {name}={coef} does not fit 8 bits")
            raw[name] = k & 0xFF
    ttr = e.ttr if e.ttr > 0 else gpst_to_bdt(e.toe)[1] - 3600.0
    start = math.floor(ttr / 30.0) * 30.0 % 604800.0
    out = []
    if not is_geo(prn):
        for n in (1, 2, 3):
            v = {"_pre": PREAMBLE, "_fra": n, "_sow": int(start + 6 * (n - 1)) % 604800, **raw}
            out.append(_pack(_layout("D1", n), v))
    else:
        for n in (1, 3, 4, 5, 6, 7, 8, 9, 10):
            v = {"_pre": PREAMBLE, "_fra": 1, "_pnum": n, "_sow": int(start + 3 * (n - 1)) % 604800, **raw}
            out.append(_pack(_layout("D2", n), v))
    return out


def _signed(u: int, f: Full) -> int:
    return u - (1 << f.bits) if f.signed and u >> (f.bits - 1) else u


def decode(sat: str, parts: dict[int, dict[str, int]], first_sow: int) -> Ephemeris:
    """An ephemeris from the unpacked D1 subframes / D2 pages of one satellite (keys: number)."""
    merged: dict[str, int] = {}
    for p in parts.values():
        merged |= {k: v for k, v in p.items() if not k.startswith(("_", "ion_"))}
    for a, low in _LOW_BITS.items():
        if a + "^" in merged:
            merged[a] = (merged.pop(a + "^") << low) | merged.pop(a + "_")
    val = {
        a: _signed(merged[a], f) * f.lsb for a, f in FIELDS.items() if a not in ("urai", "week", "toc", "toe")
    }
    week = merged["week"]
    sent = GpsTime(week, float(first_sow))  # BDT, as a week/seconds pair
    toe_b = nearest_week(merged["toe"] * 8.0, sent)
    toc_b = nearest_week(merged["toc"] * 8.0, toe_b)
    ura = merged["urai"]
    return Ephemeris(
        sat=sat,
        toc=bdt_to_gpst(toc_b.week, toc_b.tow),
        toe=bdt_to_gpst(toe_b.week, toe_b.tow),
        week=week,
        sva=URA_TABLE_M[ura] if ura < len(URA_TABLE_M) else 2.0 * URA_TABLE_M[-1],
        ttr=float(first_sow),
        **{
            **val,
            "health": int(val["health"]),
            "iode": float(round(val["iode"])),
            "iodc": float(round(val["iodc"])),
        },  # type: ignore[arg-type]
    )


def iono_of(sf1: dict[str, int]) -> IonoCoefficients | None:
    """The Klobuchar coefficients of a D1 subframe 1 (None when all are zero: not broadcast here)."""
    raw = [sf1[n] - 256 if sf1[n] >= 128 else sf1[n] for n in _ION]
    if not any(raw):
        return None
    vals = [r * q for r, q in zip(raw, ION_LSB, strict=True)]
    return IonoCoefficients((vals[0], vals[1], vals[2], vals[3]), (vals[4], vals[5], vals[6], vals[7]))
