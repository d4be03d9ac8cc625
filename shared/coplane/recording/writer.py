"""RINEX 3.04 observation and navigation writers (what the simulator and tests produce).

Deterministic by design: the same input gives a byte-identical file, so recordings can be
checked into tests and diffed. Nothing depends on the wall clock; the PGM / RUN BY / DATE line
carries a date only if the caller passes one. Only the selected signal of each system is written
(GPS C1C D1C S1C, BeiDou C2I D2I S2I by default), in the F14.3 / D19.12 formats the readers
parse, so write -> read reproduces pseudoranges to 1 mm and ephemerides to 13 digits.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from pathlib import Path

from coplane.gtime import BDS_WEEK_OFFSET, GpsTime, gpst_to_bdt
from coplane.recording.model import Ephemeris, NavData, ObsEpoch, ObsHeader, SatObservation
from coplane.recording.rinex_obs import DEFAULT_SIGNALS, SignalCodes

PROGRAM = "coplane"


def _hline(content: str, label: str) -> str:
    return f"{content:<60.60}{label:<20}".rstrip() + "\n"


def _pgm_line(date: str | None) -> str:
    return _hline(f"{PROGRAM:<20}{'':<20}{(date or ''):<20}", "PGM / RUN BY / DATE")


def _calendar(t: GpsTime, decimals: int) -> tuple[int, int, int, int, int, float]:
    """Calendar fields with seconds rounded to `decimals` (no 60.0000000 after rounding)."""
    r = GpsTime(t.week, round(t.tow, decimals))
    y, mo, d, h, mi, s = r.to_calendar()
    return y, mo, d, h, mi, round(s, decimals)


# --------------------------------------------------------------------------------------------
# Observation


def _obs_codes(sig: SignalCodes) -> list[tuple[str, str]]:
    """(code, SatObservation attribute) in RINEX order: C, L, D, S."""
    pairs = [
        (sig.pseudorange, "pseudorange_m"),
        (sig.carrier, "carrier_cycles"),
        (sig.doppler, "doppler_hz"),
        (sig.snr, "cn0_dbhz"),
    ]
    return [(c, a) for c, a in pairs if c is not None]


def _f14(v: float) -> str:
    if math.isnan(v):
        return " " * 16
    s = f"{v:14.3f}"
    if len(s) > 14:
        raise ValueError(f"value {v} does not fit RINEX F14.3")
    return s + "  "


def _obs_header(
    header: ObsHeader, codes: Mapping[str, list[tuple[str, str]]], first: GpsTime | None, date: str | None
) -> list[str]:
    out = [
        _hline(f"{3.04:9.2f}{'':11}{'OBSERVATION DATA':<20}{'M':<20}", "RINEX VERSION / TYPE"),
        _pgm_line(date),
    ]
    out.append(_hline(header.marker_name, "MARKER NAME"))
    out.append(_hline(f"{'':<20}{header.receiver:<20.20}{'':<20}", "REC # / TYPE / VERS"))
    out.append(_hline(f"{'':<20}{header.antenna:<20.20}", "ANT # / TYPE"))
    x, y, z = header.approx_position_ecef_m or (0.0, 0.0, 0.0)
    out.append(_hline(f"{x:14.4f}{y:14.4f}{z:14.4f}", "APPROX POSITION XYZ"))
    h, e, n = header.antenna_delta_hen_m
    out.append(_hline(f"{h:14.4f}{e:14.4f}{n:14.4f}", "ANTENNA: DELTA H/E/N"))
    for sys, cl in codes.items():
        names = [c for c, _ in cl]
        chunks = [names[i : i + 13] for i in range(0, len(names), 13)] or [[]]
        for k, chunk in enumerate(chunks):
            head = f"{sys}  {len(names):3d}" if k == 0 else " " * 6
            out.append(_hline(head + "".join(f" {c:3}" for c in chunk), "SYS / # / OBS TYPES"))
    out.append(_hline("DBHZ", "SIGNAL STRENGTH UNIT"))
    if header.interval_s is not None:
        out.append(_hline(f"{header.interval_s:10.3f}", "INTERVAL"))
    if first is not None:
        y_, mo, d, hh, mi, s = _calendar(first, 7)
        out.append(_hline(f"{y_:6d}{mo:6d}{d:6d}{hh:6d}{mi:6d}{s:13.7f}     GPS", "TIME OF FIRST OBS"))
    out.append(_hline("", "END OF HEADER"))
    return out


def _epoch_lines(ep: ObsEpoch, codes: Mapping[str, list[tuple[str, str]]]) -> list[str]:
    sats: list[SatObservation] = []
    for s in ep.sats:
        if s.sat[0] not in codes:
            raise ValueError(
                f"satellite {s.sat}: system {s.sat[0]} is not among the written systems {list(codes)}"
            )
        sats.append(s)
    y, mo, d, h, mi, sec = _calendar(ep.time, 7)
    line = f"> {y:4d} {mo:02d} {d:02d} {h:02d} {mi:02d}{sec:11.7f}  {ep.flag:1d}{len(sats):3d}"
    if ep.receiver_clock_offset_s != 0.0:
        line += f"{'':6}{ep.receiver_clock_offset_s:15.12f}"
    out = [line + "\n"]
    for s in sats:
        body = "".join(_f14(getattr(s, attr)) for _, attr in codes[s.sat[0]])
        out.append((s.sat + body).rstrip() + "\n")
    return out


def write_obs(
    path: str | Path,
    header: ObsHeader,
    epochs: Iterable[ObsEpoch],
    version: float = 3.04,
    signals: Mapping[str, SignalCodes] | None = None,
    date: str | None = None,
) -> Path:
    """Write RINEX 3.04 observations of the selected signal per system (default G and C)."""
    if abs(version - 3.04) > 1e-9:
        raise ValueError(f"only RINEX 3.04 is written, not {version}")
    sig = DEFAULT_SIGNALS if signals is None else signals
    codes = {sys: _obs_codes(s) for sys, s in sig.items()}
    eps = list(epochs)
    path = Path(path)
    lines = _obs_header(header, codes, eps[0].time if eps else None, date)
    for ep in eps:
        lines.extend(_epoch_lines(ep, codes))
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("".join(lines), encoding="ascii", newline="\n")
    return path


# --------------------------------------------------------------------------------------------
# Navigation


def _d19(v: float) -> str:
    """D19.12 with an E exponent (RINEX 3 allows both); tiny values that need 3 exponent digits are 0."""
    if not math.isfinite(v):
        raise ValueError(f"non-finite ephemeris value {v}")
    if v != 0.0 and abs(v) < 1e-99:
        v = 0.0
    return f"{v:19.12E}"


def _d12(v: float) -> str:
    return f"{v:12.4E}"


def _nav_record(e: Ephemeris) -> list[str]:
    if e.system == "C":
        bw, bsow = gpst_to_bdt(e.toc)
        toc_cal = GpsTime(bw + BDS_WEEK_OFFSET, bsow)  # BDT as a calendar date
        toe_sow = gpst_to_bdt(e.toe)[1]
        last = (e.ttr, e.iodc)
        line6 = (e.sva, float(e.health), e.tgd, e.tgd2)
        line5 = (e.idot, 0.0, float(e.week), 0.0)
    elif e.system == "G":
        toc_cal = e.toc
        toe_sow = e.toe.tow
        last = (e.ttr, e.fit_hours)
        line6 = (e.sva, float(e.health), e.tgd, e.iodc)
        line5 = (e.idot, 0.0, float(e.week), 0.0)
    else:
        raise ValueError(f"{e.sat}: only GPS and BeiDou ephemerides are written")
    y, mo, d, h, mi, s = _calendar(toc_cal, 0)
    rows = [
        (e.iode, e.crs, e.delta_n, e.m0),
        (e.cuc, e.e, e.cus, e.sqrt_a),
        (toe_sow, e.cic, e.omega0, e.cis),
        (e.i0, e.crc, e.omega, e.omega_dot),
        line5,
        line6,
        last,
    ]
    first = f"{e.sat} {y:4d} {mo:02d} {d:02d} {h:02d} {mi:02d} {round(s):02d}" + "".join(
        _d19(v) for v in (e.af0, e.af1, e.af2)
    )
    return [first + "\n"] + ["    " + "".join(_d19(v) for v in row) + "\n" for row in rows]


def write_nav(path: str | Path, nav: NavData, date: str | None = None) -> Path:
    """Write RINEX 3.04 mixed navigation (GPS and BeiDou records, Klobuchar header lines)."""
    lines = [
        _hline(f"{3.04:9.2f}{'':11}{'N: GNSS NAV DATA':<20}{'M: Mixed':<20}", "RINEX VERSION / TYPE"),
        _pgm_line(date),
    ]
    for sys, (a, b) in (("G", ("GPSA", "GPSB")), ("C", ("BDSA", "BDSB"))):
        ion = nav.iono.get(sys)
        if ion is not None:
            lines.append(_hline(f"{a} " + "".join(_d12(v) for v in ion.alpha), "IONOSPHERIC CORR"))
            lines.append(_hline(f"{b} " + "".join(_d12(v) for v in ion.beta), "IONOSPHERIC CORR"))
    lines.append(_hline("", "END OF HEADER"))
    for sat in sorted(nav.ephemerides, key=lambda s: ("GC".find(s[0]), s)):
        for e in nav.ephemerides[sat]:
            lines.extend(_nav_record(e))
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("".join(lines), encoding="ascii", newline="\n")
    return path
