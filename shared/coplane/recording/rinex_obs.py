"""RINEX 2.10/2.11 and 3.02-3.05 observation reader: a small, streaming, purpose-built parser.

Why not a library:
* georinex is slow and all-or-nothing: it builds xarray arrays of every requested signal, about
  45x (selected signals) to 175x (everything) slower than this module on the Nagoya rover file
  (docs/performance-rinex.md), and on bad content it raises or yields NaN without saying where.
  georinex 1.16.1 fails (DTypePromotionError) on the real RINEX 2.10 GEONET files, which carry
  event-flag-4 "RINEX FILE SPLICE" records mid-file; 1.16.2 (installed here) reads them but
  truncates their epoch tags (30.0020000 s becomes 30.001 s).
* RTKLIB via pyrtklib is the reference implementation, but it is a test-only dependency, gives no
  per-line diagnostics, cannot tell a missing value from a malformed one, and has quirks (it
  takes the Septentrio `X1` channel number as the L1 pseudorange when C1C is blank).

This reader parses only the configured signal of each wanted system, never raises on bad
content (it reports `file:line: reason` to a `Problems` collector and skips what it cannot use)
and is tested against RTKLIB on every real file in ../shared/data/real (and against georinex on a
RINEX 3.03 and a 2.10 file). It stays one file: it is one format's grammar, and RINEX 2 and 3 share
the header model, the signal selection, the epoch rules and the problem reporting below.

Rules (see ../shared/spec/fleet-recording.md):
* Event flags 2-5 announce special records (header lines) whose count is in the epoch line; they
  are skipped. Flag 6 (cycle-slip records) is skipped with its satellite records. Flag 1 (power
  failure) epochs are normal observations and kept.
* A satellite is kept only if its pseudorange on the selected signal is present and valid
  (1.5e7..5e7 m). A blank or 0.000 field means "not observed" (the RINEX and RTKLIB convention)
  and is not a problem; an unparseable, NaN, truncated or out-of-range value is counted.
* SNR outside 0..70 dB-Hz becomes NaN (counted); Doppler is kept with the RINEX sign.
* Epochs whose time does not increase are skipped (counted). A malformed epoch line skips the
  epoch and its records; reading resumes at the next valid epoch line.
* RINEX 3.02 names BeiDou B1I band "1" (C1I); 3.03+ calls it band "2" (C2I). Asking for C2I
  finds C1I in files older than 3.03. RINEX 2 codes are the first two characters (C1C -> C1).
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TextIO

from coplane.gtime import GpsTime
from coplane.recording.compressed import open_rinex_text
from coplane.recording.model import ObsEpoch, ObsHeader, SatObservation
from coplane.recording.problems import Problems, RecordingError

PSEUDORANGE_MIN_M = 1.5e7
PSEUDORANGE_MAX_M = 5.0e7
SNR_MIN_DBHZ = 0.0
SNR_MAX_DBHZ = 70.0
# An epoch more than this after the previous one is held until the next epoch shows whether the
# recording really paused (it follows) or the tag is corrupt (it does not): a day.
MAX_EPOCH_JUMP_S = 86400.0


@dataclass(frozen=True, slots=True)
class SignalCodes:
    """RINEX 3 observation codes of the one signal used per system (None: not read)."""

    pseudorange: str
    doppler: str | None = None
    snr: str | None = None
    carrier: str | None = None


DEFAULT_SIGNALS: dict[str, SignalCodes] = {
    "G": SignalCodes("C1C", "D1C", "S1C"),  # GPS L1 C/A
    "C": SignalCodes("C2I", "D2I", "S2I"),  # BeiDou B1I (C1I in RINEX 3.02)
}
DEFAULT_SYSTEMS: tuple[str, ...] = ("G", "C")

_V2_SYSTEMS = "GRSECJ"  # systems a RINEX 2 "M" file may contain; all share one type list


# --------------------------------------------------------------------------------------------
# Line source with one line of push-back and 1-based line numbers


class _Lines:
    """Iterates a text file's lines without line ends (CRLF/LF/CR) and knows the line number."""

    def __init__(self, f: TextIO) -> None:
        self._f = f
        self.lineno = 0
        self._back: str | None = None

    def next(self) -> str | None:
        if self._back is not None:
            line, self._back = self._back, None
            self.lineno += 1
            return line
        raw = self._f.readline()
        if not raw:
            return None
        self.lineno += 1
        return raw.rstrip("\r\n")

    def push_back(self, line: str) -> None:
        self._back = line
        self.lineno -= 1


# --------------------------------------------------------------------------------------------
# Header


@dataclass
class _HeaderState:
    version: float
    file_system: str
    marker_name: str = ""
    receiver: str = ""
    antenna: str = ""
    approx: tuple[float, float, float] | None = None
    delta: tuple[float, float, float] = (0.0, 0.0, 0.0)
    interval: float | None = None
    time_system: str = ""
    first_obs_line: int | None = None


def _floats(text: str, width: int, n: int) -> tuple[float, ...] | None:
    try:
        vals = tuple(float(text[i * width : (i + 1) * width] or "nan") for i in range(n))
    except ValueError:
        return None
    return vals if all(math.isfinite(v) for v in vals) else None


class _Header:
    """Parses the header lines; collects observation types per system."""

    def __init__(self, path: Path, problems: Problems) -> None:
        self.path = path
        self.problems = problems
        self.types: dict[str, list[str]] = {}
        self._declared: dict[str, int] = {}
        self._cont_sys: str | None = None
        self._v2_declared = 0
        self._v2_types: list[str] = []

    def first_line(self, line: str | None) -> _HeaderState:
        if line is None or "RINEX VERSION / TYPE" not in line:
            raise RecordingError(f"{self.path}: not a RINEX file (no 'RINEX VERSION / TYPE' on line 1)")
        try:
            version = float(line[0:9])
        except ValueError:
            raise RecordingError(f"{self.path}:1: unreadable RINEX version {line[0:9]!r}") from None
        if not 2.0 <= version < 5.0:  # RINEX 4 kept RINEX 3.05's observation records
            raise RecordingError(
                f"{self.path}:1: RINEX version {version} is not supported (2.xx, 3.0x or 4.0x)"
            )
        if line[20:21] != "O":
            raise RecordingError(f"{self.path}:1: not an observation file (type {line[20:21]!r})")
        return _HeaderState(version=version, file_system=(line[40:41].strip() or "G"))

    def line(self, st: _HeaderState, line: str, lineno: int) -> None:
        label = line[60:].strip()
        if label == "SYS / # / OBS TYPES":
            self._sys_types(line, lineno)
        elif label == "# / TYPES OF OBSERV":
            self._v2_types_line(line, lineno)
        elif label == "MARKER NAME":
            st.marker_name = line[0:60].strip()
        elif label == "REC # / TYPE / VERS":
            st.receiver = line[20:40].strip()
        elif label == "ANT # / TYPE":
            st.antenna = line[20:40].strip()
        elif label == "APPROX POSITION XYZ":
            xyz = _floats(line, 14, 3)
            if xyz is None:
                self._bad(lineno, "unreadable APPROX POSITION XYZ")
            else:
                st.approx = None if xyz == (0.0, 0.0, 0.0) else (xyz[0], xyz[1], xyz[2])
        elif label == "ANTENNA: DELTA H/E/N":
            hen = _floats(line, 14, 3)
            if hen is None:
                self._bad(lineno, "unreadable ANTENNA: DELTA H/E/N")
            else:
                st.delta = (hen[0], hen[1], hen[2])
        elif label == "INTERVAL":
            try:
                st.interval = float(line[0:10])
            except ValueError:
                self._bad(lineno, "unreadable INTERVAL")
        elif label == "TIME OF FIRST OBS":
            st.time_system = line[48:51].strip()
            st.first_obs_line = lineno

    def _bad(self, lineno: int | None, reason: str) -> None:
        self.problems.add(self.path, lineno, "header", reason)

    def _sys_types(self, line: str, lineno: int) -> None:
        sys = line[0:1]
        if sys != " ":
            try:
                n = int(line[3:6])
            except ValueError:
                self._bad(lineno, f"unreadable observation type count {line[3:6]!r}")
                self._cont_sys = None
                return
            self._declared[sys] = n
            self.types[sys] = []
            self._cont_sys = sys
        elif self._cont_sys is None:
            self._bad(lineno, "continuation of SYS / # / OBS TYPES without a system")
            return
        self.types[self._cont_sys].extend(line[7:60].split())

    def _v2_types_line(self, line: str, lineno: int) -> None:
        count = line[0:6].strip()
        if count:
            try:
                self._v2_declared = int(count)
            except ValueError:
                self._bad(lineno, f"unreadable observation type count {count!r}")
                return
            self._v2_types = []
        self._v2_types.extend(line[6:60].split())

    def finish(self, st: _HeaderState) -> dict[str, tuple[str, ...]]:
        """Observation types per system (RINEX 2: the one list, for every system the file may hold)."""
        if st.version < 3.0:
            if len(self._v2_types) != self._v2_declared:
                self._bad(
                    None,
                    f"# / TYPES OF OBSERV declares {self._v2_declared} types, lists {len(self._v2_types)}",
                )
            systems = _V2_SYSTEMS if st.file_system == "M" else st.file_system
            return {s: tuple(self._v2_types) for s in systems} if self._v2_types else {}
        for sys, n in self._declared.items():
            if len(self.types[sys]) != n:
                self._bad(
                    None, f"SYS / # / OBS TYPES for {sys} declares {n} types, lists {len(self.types[sys])}"
                )
        return {s: tuple(t) for s, t in self.types.items() if t}


# --------------------------------------------------------------------------------------------
# Signal selection: which field index holds which measurement


@dataclass(frozen=True, slots=True)
class _Fields:
    """Field indices (0-based, in header order) of the selected signal of one system."""

    pr: int
    dop: int | None
    snr: int | None
    cp: int | None


def _find(code: str | None, sys: str, types: Sequence[str], version: float) -> int | None:
    if code is None:
        return None
    if version < 3.0:
        code = code[:2]
    if code in types:
        return types.index(code)
    if sys == "C" and version < 3.03 and len(code) == 3 and code[1] == "2":
        old = code[0] + "1" + code[2]  # RINEX 3.02 B1I
        if old in types:
            return types.index(old)
    return None


def _select(
    obs_types: Mapping[str, Sequence[str]],
    signals: Mapping[str, SignalCodes],
    systems: Sequence[str],
    version: float,
) -> dict[str, _Fields]:
    out: dict[str, _Fields] = {}
    for sys in systems:
        types = obs_types.get(sys)
        if not types:
            continue
        sig = signals[sys]
        pr = _find(sig.pseudorange, sys, types, version)
        if pr is None:
            continue  # this file has no pseudorange on the selected signal for this system
        out[sys] = _Fields(
            pr,
            _find(sig.doppler, sys, types, version),
            _find(sig.snr, sys, types, version),
            _find(sig.carrier, sys, types, version),
        )
    return out


# --------------------------------------------------------------------------------------------
# Epoch lines


@dataclass(frozen=True, slots=True)
class _EpochLine:
    time: GpsTime | None  # None only for event records (flags 2-5) with a blank date
    flag: int
    n: int
    clock: float


def _make_time(y: int, mo: int, d: int, h: int, mi: int, sec: float) -> GpsTime | None:
    if not (1980 <= y <= 2200 and 1 <= mo <= 12 and 1 <= d <= 31 and 0 <= h <= 23 and 0 <= mi <= 59):
        return None
    if not 0.0 <= sec < 60.0:
        return None
    try:
        t = GpsTime.from_calendar(y, mo, d, h, mi, sec)
    except (ValueError, OverflowError):
        return None
    return GpsTime(t.week, round(t.tow, 7))  # RINEX resolves 1e-7 s; exact keys across readers


def _parse_epoch3(line: str) -> _EpochLine | None:
    """`> yyyy mm dd hh mm ss.sssssss  f nnn      clock`: None if malformed."""
    if len(line) < 35 or line[1] != " ":
        return None
    try:
        flag = int(line[31])
        n = int(line[32:35])
    except ValueError:
        return None
    if not 0 <= flag <= 6 or n < 0:
        return None
    clock = 0.0
    clk = line[41:56].strip()
    if clk:
        try:
            clock = float(clk)
        except ValueError:
            return None
        if not math.isfinite(clock):
            return None
    date = line[2:29]
    if flag >= 2 and not date.strip():
        return _EpochLine(None, flag, n, clock)
    if line[6] != " " or line[9] != " " or line[12] != " " or line[15] != " ":
        return None
    try:
        t = _make_time(
            int(line[2:6]),
            int(line[7:9]),
            int(line[10:12]),
            int(line[13:15]),
            int(line[16:18]),
            float(line[18:29]),
        )
    except ValueError:
        return None
    if t is None and flag < 2:
        return None
    return _EpochLine(t, flag, n, clock)


_EPOCH2 = re.compile(
    r" (?P<yy>[ \d]\d) (?P<mo>[ \d]\d) (?P<dd>[ \d]\d) (?P<hh>[ \d]\d) (?P<mi>[ \d]\d)"
    r"(?P<ss>[ \d]{2}\d\.\d{7})  (?P<flag>[0-6])(?P<n>[ \d]{2}\d)"
)
_EVENT2 = re.compile(r" {28}(?P<flag>[2-5])(?P<n>[ \d]{2}\d)")


def _parse_epoch2(line: str) -> _EpochLine | None:
    """RINEX 2 epoch line (2-digit year, satellite list from column 33). None if it is not one."""
    m = _EPOCH2.match(line)
    if m is None:
        e = _EVENT2.match(line)
        return _EpochLine(None, int(e["flag"]), int(e["n"]), 0.0) if e else None
    yy = int(m["yy"])
    flag = int(m["flag"])
    clock = 0.0
    clk = line[68:80].strip()
    if clk:
        try:
            clock = float(clk)
        except ValueError:
            clock = math.nan
        if not math.isfinite(clock):
            return None
    t = _make_time(
        yy + (1900 if yy >= 80 else 2000),
        int(m["mo"]),
        int(m["dd"]),
        int(m["hh"]),
        int(m["mi"]),
        float(m["ss"]),
    )
    if t is None and flag < 2:
        return None
    return _EpochLine(t, flag, int(m["n"]), clock)


# --------------------------------------------------------------------------------------------
# Observation records


class _Body:
    """Parses the records after the header into ObsEpochs (shared by RINEX 2 and 3)."""

    def __init__(
        self,
        path: Path,
        problems: Problems,
        src: _Lines,
        version: float,
        file_system: str,
        obs_types: Mapping[str, Sequence[str]],
        fields: Mapping[str, _Fields],
        wanted: Sequence[str],
    ) -> None:
        self.path = path
        self.problems = problems
        self.src = src
        self.version = version
        self.file_system = file_system
        self.obs_types = obs_types
        self.fields = fields
        self.wanted = frozenset(wanted)
        self.last: GpsTime | None = None
        # an epoch far after the last one, held until the next epoch shows whether it is a real
        # gap (the next one follows it) or a corrupt time tag (the next one does not)
        self.pending: tuple[ObsEpoch, int] | None = None

    # ---- problems
    def _p(self, kind: str, reason: str, line: int | None = None) -> None:
        self.problems.add(self.path, self.src.lineno if line is None else line, kind, reason)

    # ---- values
    def _value(self, raw: str, sat: str, code: str) -> float | None:
        """Field text -> float; None if unparseable/NaN (reported). Blank -> NaN (not observed)."""
        s = raw.strip()
        if not s:
            return math.nan
        try:
            v = float(s)
        except ValueError:
            self._p("bad-number", f"{sat} {code}: unreadable value {s!r}")
            return None
        if not math.isfinite(v):
            self._p("nan-value", f"{sat} {code}: value {s!r}")
            return None
        return v

    def _sat_obs(self, sat: str, get: _FieldGetter, f: _Fields) -> SatObservation | None:
        """The selected signal of one satellite, or None if its pseudorange is missing or invalid."""
        types = self.obs_types[sat[0]]
        pr = get.field(f.pr, sat, types[f.pr])
        if pr is None or math.isnan(pr) or pr == 0.0:
            return None
        if not PSEUDORANGE_MIN_M <= pr <= PSEUDORANGE_MAX_M:
            self._p("absurd-value", f"{sat} {types[f.pr]}: pseudorange {pr} m outside 1.5e7..5e7 m")
            return None
        dop = math.nan
        if f.dop is not None:
            d = get.field(f.dop, sat, types[f.dop])
            dop = math.nan if d is None else d
        snr = math.nan
        if f.snr is not None:
            s = get.field(f.snr, sat, types[f.snr])
            if s is not None and s != 0.0 and not math.isnan(s):
                if SNR_MIN_DBHZ <= s <= SNR_MAX_DBHZ:
                    snr = s
                else:
                    self._p("absurd-value", f"{sat} {types[f.snr]}: SNR {s} dB-Hz outside 0..70")
        cp = math.nan
        if f.cp is not None:
            c = get.field(f.cp, sat, types[f.cp])
            cp = math.nan if c is None or c == 0.0 else c
        return SatObservation(sat, pr, dop, snr, cp)

    # ---- epochs
    def _emit(self, ep: _EpochLine, sats: list[SatObservation], lineno: int) -> list[ObsEpoch]:
        """The epochs this epoch line releases (0-2): a held jump first, then itself.

        Epochs must increase. One more than MAX_EPOCH_JUMP_S after the last is held: if the next
        epoch follows it, it was a real gap; if not, it is a corrupt time tag (a wrong year, say)
        and is skipped, so it neither stops every later epoch as "not after" nor stretches the
        replay over decades.
        """
        assert ep.time is not None
        out: list[ObsEpoch] = []
        if self.pending is not None:
            held, held_line = self.pending
            self.pending = None
            if ep.time - held.time > 0.0:
                out.append(held)
                self.last = held.time
            else:
                self._jump(held, held_line, f"the next epoch {ep.time} does not follow it")
        if self.last is not None and ep.time <= self.last:
            self._p("non-monotonic-time", f"epoch {ep.time} is not after {self.last}: skipped", lineno)
            return out
        seen: set[str] = set()
        kept: list[SatObservation] = []
        for s in sats:
            if s.sat in seen:
                self._p("duplicate-satellite", f"{s.sat} twice in epoch {ep.time}: kept the first", lineno)
                continue
            seen.add(s.sat)
            kept.append(s)
        epoch = ObsEpoch(ep.time, tuple(kept), ep.flag, ep.clock)
        if self.last is not None and ep.time - self.last > MAX_EPOCH_JUMP_S:
            self.pending = (epoch, lineno)
            return out
        self.last = ep.time
        out.append(epoch)
        return out

    def _jump(self, held: ObsEpoch, lineno: int, why: str) -> None:
        after = (
            f"{held.time - self.last:.0f} s after epoch {self.last}" if self.last is not None else "far ahead"
        )
        self._p(
            "epoch-time-jump", f"epoch {held.time} is {after} and {why}: a corrupt time tag, skipped", lineno
        )

    def _flush(self) -> None:
        """End of file: a held jump that nothing followed is a corrupt time tag."""
        if self.pending is not None:
            self._jump(*self.pending, "nothing follows it")
            self.pending = None

    def _resync(self, is_epoch: Callable[[str], bool]) -> int:
        """Skip lines until the next epoch line (pushed back); returns how many were skipped."""
        skipped = 0
        while (line := self.src.next()) is not None:
            if is_epoch(line):
                self.src.push_back(line)
                break
            skipped += 1
        return skipped

    def _malformed_epoch(self, lineno: int, line: str, is_epoch: Callable[[str], bool]) -> None:
        skipped = self._resync(is_epoch)
        self._p(
            "malformed-epoch",
            f"malformed epoch line {line[:40].rstrip()!r}: skipped it and {skipped} following line(s)",
            lineno,
        )

    def _stray(self, lineno: int, line: str, kind: str, is_epoch: Callable[[str], bool]) -> None:
        """A line where an epoch line should be: skip to the next valid epoch line, report once."""
        skipped = self._resync(is_epoch)
        what = "malformed epoch line" if kind == "malformed-epoch" else "line outside any epoch"
        self._p(kind, f"{what} {line[:40].rstrip()!r}: skipped it and {skipped} following line(s)", lineno)

    def _skip_special(self, n: int, is_epoch: Callable[[str], bool]) -> None:
        """Skip the `n` records announced by an event flag (stop early at an epoch line)."""
        for _ in range(n):
            line = self.src.next()
            if line is None:
                return
            if is_epoch(line):
                self._p("short-epoch", "event record count larger than the records present")
                self.src.push_back(line)
                return

    # ---- RINEX 3
    def _is_epoch3(self, line: str) -> bool:
        return line.startswith(">") and _parse_epoch3(line) is not None

    def epochs3(self) -> Iterator[ObsEpoch]:
        src = self.src
        while (line := src.next()) is not None:
            if not line.startswith(">"):
                if line.strip():
                    self._stray(src.lineno, line, "unexpected-line", self._is_epoch3)
                continue
            lineno = src.lineno
            ep = _parse_epoch3(line)
            if ep is None:
                self._malformed_epoch(lineno, line, self._is_epoch3)
                continue
            if ep.flag >= 2:
                self._skip_special(ep.n, self._is_epoch3)
                continue
            sats = self._records3(ep.n)
            yield from self._emit(ep, sats, lineno)
        self._flush()

    def _records3(self, n: int) -> list[SatObservation]:
        """Read `n` satellite records; garbage lines do not count; stop early at an epoch line."""
        src = self.src
        sats: list[SatObservation] = []
        got = 0
        while got < n:
            line = src.next()
            if line is None:
                self._p("short-epoch", f"file ends after {got} of {n} satellite records")
                break
            if line.startswith(">"):
                self._p("short-epoch", f"epoch has {got} of {n} satellite records", src.lineno - 1)
                src.push_back(line)
                break
            sys = line[0:1]
            prn = line[1:3]
            if not (
                sys.isalpha() and len(prn) == 2 and prn[1].isdigit() and (prn[0] == " " or prn[0].isdigit())
            ):
                self._p("malformed-line", f"not a satellite record: {line[:40].rstrip()!r}")
                continue
            got += 1
            f = self.fields.get(sys)
            if f is None:
                if sys not in self.obs_types and sys in self.wanted:
                    self._p("undeclared-system", f"system {sys} has no SYS / # / OBS TYPES: record skipped")
                continue
            sat = f"{sys}{int(prn):02d}"
            s = self._sat_obs(sat, _FieldGetter(self, (line,), 3, 10**9), f)
            if s is not None:
                sats.append(s)
        return sats

    # ---- RINEX 2
    def _is_epoch2(self, line: str) -> bool:
        return _parse_epoch2(line) is not None

    def epochs2(self) -> Iterator[ObsEpoch]:
        src = self.src
        ntypes = max((len(t) for t in self.obs_types.values()), default=0)
        lines_per_sat = max(1, -(-ntypes // 5))
        while (line := src.next()) is not None:
            ep = _parse_epoch2(line)
            if ep is None:
                if line.strip():
                    looks_like_epoch = line[:1] == " " and line[28:29].isdigit()
                    kind = "malformed-epoch" if looks_like_epoch else "unexpected-line"
                    self._stray(src.lineno, line, kind, self._is_epoch2)
                continue
            lineno = src.lineno
            if ep.flag in (2, 3, 4, 5):
                self._skip_special(ep.n, self._is_epoch2)
                continue
            sat_ids = self._sat_list2(line, ep.n)
            if sat_ids is None:
                self._malformed_epoch(lineno, line, self._is_epoch2)
                continue
            if ep.flag == 6:
                self._skip_records2(len(sat_ids) * lines_per_sat)
                continue
            sats = self._records2(sat_ids, lines_per_sat)
            yield from self._emit(ep, sats, lineno)
        self._flush()

    def _sat_list2(self, line: str, n: int) -> list[str] | None:
        ids: list[str] = []
        text = line[32:68]
        while True:
            for k in range(0, len(text.rstrip()), 3):
                tok = text[k : k + 3]
                sys = tok[0] if tok[0] != " " else (self.file_system if self.file_system != "M" else "G")
                prn = tok[1:3]
                if not (sys.isalpha() and prn.strip().isdigit()):
                    return None
                ids.append(f"{sys}{int(prn):02d}")
                if len(ids) == n:
                    return ids
            if len(ids) >= n:
                return ids
            nxt = self.src.next()
            if nxt is None or nxt[:32].strip():
                if nxt is not None:
                    self.src.push_back(nxt)
                return None
            text = nxt[32:68]

    def _skip_records2(self, nlines: int) -> None:
        for _ in range(nlines):
            line = self.src.next()
            if line is None:
                return
            if self._is_epoch2(line):
                self.src.push_back(line)
                return

    def _records2(self, sat_ids: list[str], lines_per_sat: int) -> list[SatObservation]:
        sats: list[SatObservation] = []
        for i, sat in enumerate(sat_ids):
            lines: list[str] = []
            for _ in range(lines_per_sat):
                line = self.src.next()
                if line is None or self._is_epoch2(line):
                    if line is not None:
                        self.src.push_back(line)
                    self._p("short-epoch", f"epoch has {i} of {len(sat_ids)} satellite records")
                    return sats
                lines.append(line)
            f = self.fields.get(sat[0])
            if f is None:
                continue
            s = self._sat_obs(sat, _FieldGetter(self, tuple(lines), 0, 5), f)
            if s is not None:
                sats.append(s)
        return sats


class _FieldGetter:
    """Reads field `i` (F14.3 + LLI + SSI = 16 columns) of a record spread over one or more lines."""

    __slots__ = ("_body", "_ends", "_lines", "_offset", "_per_line", "_truncated")

    def __init__(self, body: _Body, lines: tuple[str, ...], offset: int, per_line: int) -> None:
        self._body = body
        self._lines = lines
        self._ends = [len(x.rstrip()) for x in lines]
        self._offset = offset
        self._per_line = per_line
        self._truncated = False

    def field(self, i: int, sat: str, code: str) -> float | None:
        k = i // self._per_line
        if k >= len(self._lines):
            return math.nan
        line = self._lines[k]
        start = self._offset + 16 * (i % self._per_line)
        raw = line[start : start + 14]
        end = self._ends[k]
        if start < end < start + 14:
            if not self._truncated:
                self._truncated = True
                self._body._p("truncated-line", f"{sat} {code}: line ends inside the field ({raw.strip()!r})")
            return None
        return self._body._value(raw, sat, code)


# --------------------------------------------------------------------------------------------
# Public API


def _open(path: Path) -> TextIO:
    try:
        return open_rinex_text(path)  # compressed (.gz, .Z, Compact RINEX) or plain
    except OSError as exc:
        raise RecordingError(f"{path}: cannot read observation file ({exc.strerror or exc})") from exc


def iter_obs(
    path: str | Path,
    problems: Problems,
    signals: Mapping[str, SignalCodes] | None = None,
    systems: Sequence[str] = DEFAULT_SYSTEMS,
) -> tuple[ObsHeader, Iterator[ObsEpoch]]:
    """Parse the header now (raising RecordingError if unusable) and stream the epochs lazily."""
    path = Path(path)
    sig = dict(DEFAULT_SIGNALS if signals is None else signals)
    missing = [s for s in systems if s not in sig]
    if missing:
        raise ValueError(f"no SignalCodes configured for system(s) {missing}")
    f = _open(path)
    try:
        header, body = _read_header(path, problems, _Lines(f), sig, systems)
    except Exception:
        f.close()
        raise
    return header, _stream(f, body)


def _stream(f: TextIO, body: _Body) -> Iterator[ObsEpoch]:
    with f:
        try:
            yield from (body.epochs2() if body.version < 3.0 else body.epochs3())
        except (OSError, UnicodeError) as exc:
            body._p("unreadable", f"reading stopped: {exc}")


def read_obs(
    path: str | Path,
    problems: Problems,
    signals: Mapping[str, SignalCodes] | None = None,
    systems: Sequence[str] = DEFAULT_SYSTEMS,
) -> tuple[ObsHeader, list[ObsEpoch]]:
    """Read a RINEX observation file: header and the epochs of the selected signals (G and C)."""
    header, epochs = iter_obs(path, problems, signals, systems)
    return header, list(epochs)


def _read_header(
    path: Path, problems: Problems, src: _Lines, signals: Mapping[str, SignalCodes], systems: Sequence[str]
) -> tuple[ObsHeader, _Body]:
    h = _Header(path, problems)
    try:
        st = h.first_line(src.next())
    except (OSError, UnicodeError) as exc:
        raise RecordingError(f"{path}: cannot read observation file ({exc})") from exc
    is_epoch = _parse_epoch2 if st.version < 3.0 else _parse_epoch3
    while True:
        line = src.next()
        if line is None:
            raise RecordingError(f"{path}: header has no END OF HEADER line")
        if line[60:].strip() == "END OF HEADER":
            break
        if h.types or h._v2_types:
            ep = is_epoch(line)
            if ep is not None and ep.time is not None:
                problems.add(path, src.lineno, "missing-end-of-header", "data starts before END OF HEADER")
                src.push_back(line)
                break
        h.line(st, line, src.lineno)
    obs_types = h.finish(st)
    if not obs_types:
        raise RecordingError(f"{path}: header declares no observation types")
    ts = st.time_system or ("GPS" if st.file_system in ("G", "M") else st.file_system)
    ts = {"G": "GPS", "C": "BDT", "E": "GAL", "R": "GLO", "J": "QZS"}.get(ts, ts)
    if ts != "GPS":
        problems.add(
            path,
            st.first_obs_line,
            "time-system",
            f"time system {ts!r}: epochs are read as GPS time (the format requires GPS)",
        )
    header = ObsHeader(
        version=st.version,
        marker_name=st.marker_name,
        receiver=st.receiver,
        antenna=st.antenna,
        approx_position_ecef_m=st.approx,
        antenna_delta_hen_m=st.delta,
        obs_types=obs_types,
        interval_s=st.interval,
        time_system=ts,
    )
    fields = _select(obs_types, signals, systems, st.version)
    return header, _Body(path, problems, src, st.version, st.file_system, obs_types, fields, systems)
