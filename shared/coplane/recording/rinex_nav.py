"""RINEX 4.00-4.02 and 3.02-3.05 (mixed or per-system) and RINEX 2.10/2.11 GPS navigation reader.

Produces `Ephemeris` for GPS LNAV and BeiDou D1/D2 records and `IonoCoefficients` from the
header (`IONOSPHERIC CORR` GPSA/GPSB/BDSA/BDSB, RINEX 2 `ION ALPHA`/`ION BETA`) or, in RINEX 4,
from the Klobuchar `ION` records (GPS `LNAV`, BeiDou `D1D2`; the first readable one of a system).
Records of other systems (R and S: 4 lines, R from RINEX 3.05 on 5, E/J/I: 8 lines) are skipped. Records are found by
their first line (a satellite id and a date), not by counting lines, so a broken record cannot
shift the rest of the file; a record of a wanted system that is broken is skipped with
`file:line` reason. RINEX 4 (what IGS broadcast files such as BRD400DLR are today) opens each
record with a `> EPH G01 LNAV` line naming its type, satellite and message: the body of an `EPH`
GPS LNAV or BeiDou D1/D2 record is RINEX 3's, and every other record (CNAV, other systems,
`STO`, `EOP`, NeQuick `ION`) is skipped up to the next `>` line.

BeiDou epoch (toc), toe and transmission times are BDT in the file: toc/toe are converted to
GPST here (gtime.bdt_to_gpst) so all downstream time arithmetic is in one scale; `week` stays
the broadcast BDT week and `ttr` the broadcast seconds of week. Like RTKLIB, toe is moved to the
week that puts it within half a week of toc (the week number in the record goes with toe, but
some writers disagree at week rollovers).

Sanity limits (a broken record is dropped, not repaired): sqrt(A) within 2500..10000 m^0.5
(GPS ~5153, BeiDou MEO ~5282, IGSO/GEO ~6493), eccentricity within 0..1, all fields finite.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable
from pathlib import Path

from coplane.gtime import BDS_WEEK_OFFSET, SECONDS_PER_WEEK, GpsTime, bdt_to_gpst
from coplane.recording.compressed import open_rinex_text
from coplane.recording.model import Ephemeris, IonoCoefficients, NavData
from coplane.recording.problems import Problems, RecordingError

WANTED = ("G", "C")
# Lines per record in RINEX 3 navigation files (first line included).
RECORD_LINES = {"G": 8, "C": 8, "E": 8, "J": 8, "I": 8, "R": 4, "S": 4}
SQRT_A_RANGE = (2500.0, 10000.0)
# RINEX 4 record types, and the messages read: GPS LNAV, BeiDou D1 (MEO/IGSO) and D2 (GEO)
# ephemerides, and their Klobuchar ionosphere; the others (CNAV, CNV1-3, ...) are skipped
RECORD_TYPES4 = ("EPH", "ION", "STO", "EOP")
EPHEMERIS_MESSAGES4 = {("G", "LNAV"), ("C", "D1"), ("C", "D2")}
KLOBUCHAR_MESSAGES4 = {("G", "LNAV"), ("C", "D1D2")}


def _num(text: str) -> float:
    """A D19.12/D12.4 field; blank means 0 (spare fields). Raises ValueError if unreadable."""
    s = text.strip()
    if not s:
        return 0.0
    v = float(s.replace("D", "E").replace("d", "e"))
    if not math.isfinite(v):
        raise ValueError(f"non-finite value {s!r}")
    return v


def _fields(text: str, n: int, line_index: int) -> list[float]:
    """`n` right-aligned 19-column fields; a non-blank field not ending in its last column was cut."""
    out = []
    for m in range(n):
        raw = text[m * 19 : (m + 1) * 19]
        if raw.strip() and (len(raw) < 19 or raw[-1] == " "):
            raise ValueError(
                f"field {m + 1} of record line {line_index + 1} is truncated or misaligned ({raw!r})"
            )
        out.append(_num(raw))
    return out


def _adjust_week(t: GpsTime, ref: GpsTime) -> GpsTime:
    dt = t - ref
    if dt > SECONDS_PER_WEEK / 2:
        return t + (-SECONDS_PER_WEEK)
    if dt < -SECONDS_PER_WEEK / 2:
        return t + SECONDS_PER_WEEK
    return t


class _NavFile:
    def __init__(self, path: Path, problems: Problems) -> None:
        self.path = path
        self.problems = problems
        self.nav = NavData()
        self.version = 0.0
        self._iono: dict[str, list[tuple[float, ...] | None]] = {}

    def _p(self, line: int | None, kind: str, reason: str) -> None:
        self.problems.add(self.path, line, kind, reason)

    # ---- header
    def header(self, lines: list[str]) -> int:
        """Parse the header; returns the index of the first data line."""
        if not lines or "RINEX VERSION / TYPE" not in lines[0]:
            raise RecordingError(f"{self.path}: not a RINEX file (no 'RINEX VERSION / TYPE' on line 1)")
        try:
            self.version = float(lines[0][0:9])
        except ValueError:
            raise RecordingError(f"{self.path}:1: unreadable RINEX version {lines[0][0:9]!r}") from None
        kind = lines[0][20:21]
        if not 2.0 <= self.version < 5.0:
            raise RecordingError(
                f"{self.path}:1: RINEX version {self.version} is not supported (2.xx, 3.0x or 4.0x)"
            )
        if self.version < 3.0 and kind != "N":
            raise RecordingError(f"{self.path}:1: RINEX 2 file type {kind!r} is not GPS navigation ('N')")
        if self.version >= 3.0 and kind != "N":
            raise RecordingError(f"{self.path}:1: not a navigation file (type {kind!r})")
        for i, line in enumerate(lines[1:], start=1):
            label = line[60:].strip()
            if label == "END OF HEADER":
                self._finish_iono()
                return i + 1
            if label == "IONOSPHERIC CORR":
                self._iono_line(line[0:4].strip(), line[5:53], i + 1, 12)
            elif label == "ION ALPHA":
                self._iono_line("GPSA", line[2:50], i + 1, 12)
            elif label == "ION BETA":
                self._iono_line("GPSB", line[2:50], i + 1, 12)
        raise RecordingError(f"{self.path}: header has no END OF HEADER line")

    def _iono_line(self, key: str, text: str, lineno: int, width: int) -> None:
        if key not in ("GPSA", "GPSB", "BDSA", "BDSB"):
            return
        try:
            vals = tuple(_num(text[k * width : (k + 1) * width]) for k in range(4))
        except ValueError:
            self._p(lineno, "header", f"unreadable {key} ionosphere coefficients")
            self._iono[key] = [None]
            return
        self._iono.setdefault(key, []).append(vals)

    def _finish_iono(self) -> None:
        for sys, a, b in (("G", "GPSA", "GPSB"), ("C", "BDSA", "BDSB")):
            alpha, beta = self._iono.get(a, [None])[0], self._iono.get(b, [None])[0]
            if alpha is not None and beta is not None:
                self.nav.iono[sys] = IonoCoefficients(
                    (alpha[0], alpha[1], alpha[2], alpha[3]), (beta[0], beta[1], beta[2], beta[3])
                )
            elif (a in self._iono) != (b in self._iono):
                have, missing = (a, b) if a in self._iono else (b, a)
                self._p(None, "header", f"ionosphere: {have} without {missing}: not used")

    # ---- records
    def _is_start3(self, line: str) -> bool:
        return len(line) >= 23 and line[0].isalpha() and line[1:3].strip().isdigit() and line[3] == " "

    def _is_start2(self, line: str) -> bool:
        return len(line) >= 22 and line[0:2].strip().isdigit() and line[2] == " "

    def records(self, lines: list[str], first: int) -> None:
        if self.version >= 4.0:
            self._records4(lines, first)
            return
        is_start = self._is_start3 if self.version >= 3.0 else self._is_start2
        i = first
        n = len(lines)
        while i < n:
            line = lines[i]
            if not line.strip():
                i += 1
                continue
            if not is_start(line):
                j = i + 1
                while j < n and not is_start(lines[j]):
                    j += 1
                self._p(
                    i + 1,
                    "unexpected-line",
                    f"{j - i} line(s) outside any record skipped: {line[:40].rstrip()!r}",
                )
                i = j
                continue
            j = i + 1
            while j < n and not is_start(lines[j]) and lines[j][:3].strip() == "":
                j += 1
            self._record(lines[i:j], i + 1)
            i = j

    def _records4(self, lines: list[str], first: int) -> None:
        """RINEX 4: each record is its `>` line and the lines up to the next one."""
        starts = [i for i in range(first, len(lines)) if lines[i].startswith(">")] + [len(lines)]
        stray = [i for i in range(first, starts[0]) if lines[i].strip()]
        if stray:
            self._p(
                stray[0] + 1,
                "unexpected-line",
                f"{len(stray)} line(s) outside any record skipped: {lines[stray[0]][:40].rstrip()!r}",
            )
        for i, j in itertools.pairwise(starts):
            body = [x for x in lines[i + 1 : j] if x.strip()]
            head = lines[i][1:].split()
            if len(head) < 2 or head[0] not in RECORD_TYPES4:
                self._p(
                    i + 1, "malformed-record", f"unreadable record line {lines[i][:40].rstrip()!r}: skipped"
                )
                continue
            kind, sys, message = head[0], head[1][0], head[-1]
            if kind == "EPH" and (sys, message) in EPHEMERIS_MESSAGES4:
                if not body or not self._is_start3(body[0]):
                    self._p(
                        i + 2,
                        "malformed-record",
                        f"{head[1]} {message}: no satellite and epoch line: skipped",
                    )
                    continue
                self._record(body, i + 2)
            elif kind == "ION" and (sys, message) in KLOBUCHAR_MESSAGES4:
                self._klobuchar4(sys, body, i + 2)

    def _klobuchar4(self, sys: str, body: list[str], lineno: int) -> None:
        """A RINEX 4 Klobuchar `ION` record: transmission time and alpha0-2, alpha3 and beta0-2,
        beta3 and a region code; the first readable one of a system is kept."""
        if sys in self.nav.iono:
            return
        try:
            if len(body) < 3:
                raise ValueError(f"{len(body)} data line(s), expected 3")
            self._date(body[0][4:23])
            vals = _fields(body[0][23:], 3, 0) + _fields(body[1][4:], 4, 1) + _fields(body[2][4:], 1, 2)
        except ValueError as exc:
            self._p(lineno, "malformed-record", f"{sys} ionosphere (ION): {exc}: not used")
            return
        self.nav.iono[sys] = IonoCoefficients(
            (vals[0], vals[1], vals[2], vals[3]), (vals[4], vals[5], vals[6], vals[7])
        )

    def _record(self, rec: list[str], lineno: int) -> None:
        if self.version >= 3.0:
            sys = rec[0][0]
            # RINEX 3.05 gave a GLONASS record a fourth line of broadcast orbits (status flags)
            want = 5 if sys == "R" and self.version >= 3.05 else RECORD_LINES.get(sys)
            if want is None:
                self._p(lineno, "malformed-record", f"unknown system {sys!r}: record skipped")
                return
            if sys not in WANTED:
                if len(rec) != want:
                    self._p(lineno, "malformed-record", f"{sys} record has {len(rec)} lines, expected {want}")
                return
            sat = f"{sys}{int(rec[0][1:3]):02d}"
            date, first_vals, indent = rec[0][4:23], rec[0][23:], 4
        else:
            sys = "G"
            sat = f"G{int(rec[0][0:2]):02d}"
            date, first_vals, indent = rec[0][3:22], rec[0][22:], 3
        if len(rec) < 8:
            self._p(lineno, "malformed-record", f"{sat}: record has {len(rec)} lines, expected 8: skipped")
            return
        if len(rec) > 8:
            self._p(
                lineno + 8, "unexpected-line", f"{sat}: {len(rec) - 8} extra line(s) after the record skipped"
            )
        try:
            toc_cal = self._date(date)
            data = _fields(first_vals, 3, 0)
            for k, line in enumerate(rec[1:8], start=1):
                data.extend(_fields(line[indent:], 4, k))
        except ValueError as exc:
            self._p(lineno, "malformed-record", f"{sat}: {exc}: record skipped")
            return
        eph = self._ephemeris(sat, toc_cal, data, lineno)
        if eph is not None:
            self.nav.add(eph)

    def _date(self, text: str) -> GpsTime:
        f = text.split()
        if len(f) != 6:
            raise ValueError(f"unreadable epoch {text.strip()!r}")
        y, mo, d, h, mi = (int(x) for x in f[:5])
        sec = float(f[5])
        if self.version < 3.0:
            y += 1900 if y >= 80 else 2000
        if not (
            1980 <= y <= 2200
            and 1 <= mo <= 12
            and 1 <= d <= 31
            and 0 <= h <= 23
            and 0 <= mi <= 59
            and 0 <= sec < 60
        ):
            raise ValueError(f"invalid epoch {text.strip()!r}")
        return GpsTime.from_calendar(y, mo, d, h, mi, sec)

    def _ephemeris(self, sat: str, toc_cal: GpsTime, d: list[float], lineno: int) -> Ephemeris | None:
        sqrt_a, e = d[10], d[8]
        if not (SQRT_A_RANGE[0] <= sqrt_a <= SQRT_A_RANGE[1]) or not (0.0 <= e < 1.0):
            self._p(lineno, "absurd-value", f"{sat}: sqrt(A) {sqrt_a} or e {e} out of range: record skipped")
            return None
        week = int(d[21])
        if sat[0] == "C":
            toc = bdt_to_gpst(toc_cal.week - BDS_WEEK_OFFSET, toc_cal.tow)
            toe = _adjust_week(bdt_to_gpst(week, d[11]), toc)
            tgd2, iodc, fit = d[26], d[28], 0.0
        else:
            toc = toc_cal
            toe = _adjust_week(GpsTime(week, d[11]), toc)
            tgd2, iodc, fit = 0.0, d[26], d[28]
        return Ephemeris(
            sat=sat,
            toc=toc,
            af0=d[0],
            af1=d[1],
            af2=d[2],
            iode=d[3],
            crs=d[4],
            delta_n=d[5],
            m0=d[6],
            cuc=d[7],
            e=e,
            cus=d[9],
            sqrt_a=sqrt_a,
            toe=toe,
            cic=d[12],
            omega0=d[13],
            cis=d[14],
            i0=d[15],
            crc=d[16],
            omega=d[17],
            omega_dot=d[18],
            idot=d[19],
            week=week,
            sva=d[23],
            health=int(d[24]),
            tgd=d[25],
            tgd2=tgd2,
            iodc=iodc,
            ttr=d[27],
            fit_hours=fit,
        )


def read_nav(path: str | Path, problems: Problems) -> NavData:
    """GPS and BeiDou ephemerides and ionosphere coefficients of one RINEX navigation file."""
    path = Path(path)
    try:
        with open_rinex_text(path) as f:  # compressed (.gz, .Z) or plain
            lines = [x.rstrip("\r\n") for x in f]
    except OSError as exc:
        raise RecordingError(f"{path}: cannot read navigation file ({exc.strerror or exc})") from exc
    nf = _NavFile(path, problems)
    first = nf.header(lines)
    nf.records(lines, first)
    return nf.nav


def read_nav_files(paths: Iterable[str | Path], problems: Problems) -> NavData:
    """Several navigation files merged (duplicates dropped; first file's ionosphere wins)."""
    nav = NavData()
    for p in paths:
        nav.merge(read_nav(p, problems))
    return nav
