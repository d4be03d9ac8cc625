"""Reference trajectories written by other tools: RTKLIB solution files and GNSS/INS text exports.

A test drive's reference rarely comes as coplane's truth CSV. It comes out of RTKLIB's RTK or PPK
(`.pos`, in any of its time and position layouts), or out of a GNSS/INS post-processor such as
NovAtel Inertial Explorer, whose text export (GPS week and seconds, latitude and longitude in
degrees-minutes-seconds, ellipsoidal height) is the ground truth UrbanNav publishes.
`recording init --truth ID=FILE` converts either into truth/<id>.csv, the recording's one truth
format (`plan._truths`), and coplane reads RTKLIB's solutions for its `rtklib` row here too.

Written here because no Python package we use reads them with per-line problems: pyrtklib (an
optional dependency) reads solutions only through RTKLIB's C `readsol`, which skips bad lines
silently, and no package reads Inertial Explorer's exports. Every bad line is counted in
`Problems` with its line number and skipped; a file whose layout cannot be told raises
`RecordingError` naming it.
"""

from __future__ import annotations

import math
import re
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from coplane.geo import enu_rotation, geodetic_to_ecef
from coplane.gtime import SECONDS_PER_WEEK, GpsTime, gps_minus_utc_s
from coplane.recording.csvfiles import EARTH_RADIUS_BOUNDS_M, read_truth
from coplane.recording.model import TruthPoint
from coplane.recording.problems import Problems, RecordingError
from coplane.typing import Vec

# RTKLIB solution quality flags (Q column; 7 is RTKLIB's SOLQ_DR, a dead-reckoned solution)
Q_FIX, Q_FLOAT, Q_SBAS, Q_DGPS, Q_SINGLE, Q_PPP, Q_DR = 1, 2, 3, 4, 5, 6, 7
Q_NAMES = {
    Q_FIX: "fix",
    Q_FLOAT: "float",
    Q_SBAS: "sbas",
    Q_DGPS: "dgps",
    Q_SINGLE: "single",
    Q_PPP: "ppp",
    Q_DR: "dr",
}
JST_MINUS_UTC_S = 9 * 3600  # RTKLIB's third time system, Japan Standard Time
_CALENDAR = re.compile(r"\d{4}/\d{1,2}/\d{1,2}")


@dataclass(frozen=True)
class PosRecord:
    """One solution of an RTKLIB .pos file: ECEF position, its 3x3 ECEF covariance (zeros when
    the file gives none), quality flag, satellite count and the age of the differential
    corrections (0 when none; `read_pos` does not read it back)."""

    time: GpsTime
    ecef: Vec
    covariance: Vec
    quality: int
    n_sats: int
    age_s: float = 0.0


@dataclass
class Trajectory:
    """A reference trajectory read from another tool's file: its points in time order, what the
    file was, how many rows each quality flag had (RTKLIB's Q, Inertial Explorer's Q), and how
    many rows were left out as too weak to be a reference."""

    points: list[TruthPoint]
    qualities: Counter[int] = field(default_factory=Counter)
    kind: str = "RTKLIB .pos"  # or "Inertial Explorer text", "coplane truth CSV"
    left_out: int = 0

    def describe(self) -> str:
        """What was taken, for `recording init`'s notes."""
        if self.kind.startswith("RTKLIB"):
            flags = ", ".join(f"{Q_NAMES.get(q, f'Q={q}')} {k}" for q, k in sorted(self.qualities.items()))
        else:
            flags = ", ".join(f"Q{q} {k}" for q, k in sorted(self.qualities.items()))
        article = "a" if self.kind.startswith("coplane") else "an"  # "an RTKLIB", "an Inertial"
        text = f"{len(self.points)} points from {article} {self.kind} file ({flags or 'no quality column'})"
        if self.left_out:
            text += f"; {self.left_out} rows without a fixed ambiguity left out"
        elif self.kind.startswith("RTKLIB") and Q_FIX not in self.qualities:
            text += "; no row has a fixed ambiguity, so the reference is only as good as its float or code solution"
        return text


@dataclass(frozen=True)
class _PosLayout:
    """How an RTKLIB file lays out its rows: time as week + seconds or calendar, in which time
    system, and the position as "xyz", "llh" (degrees) or "dms"."""

    week_tow: bool
    time_system: str  # GPST, UTC or JST
    position: str


def _lines(path: Path) -> Iterator[tuple[int, str]]:
    """(line number, text) of a text file, read as it goes (a day at 100 Hz is a large file; a
    binary one gets replacement characters and fails row by row); RecordingError if it cannot be
    opened."""
    try:
        f = path.open("r", encoding="utf-8", errors="replace")
    except OSError as exc:
        raise RecordingError(f"{path}: cannot read ({exc.strerror or exc})") from exc
    with f:
        for n, line in enumerate(f, start=1):
            yield n, line.rstrip("\r\n")


def sniff(path: Path) -> str:
    """Which trajectory format `path` holds: "csv" (coplane's truth CSV), "pos" (RTKLIB) or "ie"
    (an Inertial Explorer text export); RecordingError naming the forms otherwise."""
    for _, line in _lines(path):
        s = line.strip()
        if not s:
            continue
        low = s.lower()
        if low.startswith("%") or _CALENDAR.match(s) or re.match(r"\d{3,4}\s+\d+(\.\d*)?\s", s):
            return "pos"
        if "gps_week" in low and "tow_s" in low:
            return "csv"
        if "gpstime" in low and "latitude" in low and "longitude" in low:
            return "ie"
        break
    raise RecordingError(
        f"{path}: not a trajectory coplane reads: expected its truth CSV (gps_week,tow_s,x_m,y_m,z_m), "
        "an RTKLIB solution file (.pos) or an Inertial Explorer text export (GPSTime, Latitude, "
        "Longitude, H-Ell columns)"
    )


# --------------------------------------------------------------------------------------------
# RTKLIB .pos


def _pos_layout(header: str, tokens: list[str]) -> _PosLayout:
    """The layout from RTKLIB's column header line (`%  GPST  latitude(deg) ...`), or guessed from
    a first data row when the file has no header (RTKLIB's outhead off: its default is GPST)."""
    week_tow = not _CALENDAR.match(tokens[0])
    if not header:
        if abs(float(tokens[2])) > 1e5:
            return _PosLayout(week_tow, "GPST", "xyz")
        return _PosLayout(week_tow, "GPST", "dms" if re.fullmatch(r"-?\d+", tokens[2]) else "llh")
    low = header.lower()
    system = re.match(r"%\s*(gpst|utc|jst)\b", low)
    if "x-ecef" in low:
        position = "xyz"
    elif "latitude(d'" in low:
        position = "dms"
    elif "latitude(deg)" in low:
        position = "llh"
    else:
        raise ValueError(
            "positions are neither ECEF, latitude/longitude/height nor degrees-minutes-seconds "
            "(a baseline cannot be a reference trajectory)"
        )
    return _PosLayout(week_tow, system.group(1).upper() if system else "GPST", position)


def _pos_time(tokens: list[str], layout: _PosLayout) -> GpsTime:
    """A row's time as GPS time (RTKLIB writes UTC or JST when asked to)."""
    if layout.week_tow:
        week, tow = int(tokens[0]), float(tokens[1])
        if week < 0 or not 0.0 <= tow < SECONDS_PER_WEEK:
            raise ValueError(f"time {week} {tow} out of range")
        t = GpsTime(week, tow)
    else:
        y, mo, d = (int(v) for v in tokens[0].split("/"))
        hh, mi, ss = tokens[1].split(":")
        t = GpsTime.from_calendar(y, mo, d, int(hh), int(mi), float(ss))
    if layout.time_system == "GPST":
        return t
    if layout.time_system == "JST":
        t = t + -JST_MINUS_UTC_S
    return t + gps_minus_utc_s(t)


def _dms(deg: str, minutes: str, seconds: str) -> float:
    """Degrees from RTKLIB's or Inertial Explorer's "D M S" (the sign on the degrees, "-0" too)."""
    value = abs(float(deg)) + float(minutes) / 60.0 + float(seconds) / 3600.0
    return -value if deg.strip().startswith("-") else value


def _geodetic(lat_deg: float, lon_deg: float, h: float) -> Vec:
    """ECEF of a latitude / longitude (degrees) and ellipsoidal height; ValueError when out of range."""
    if not (abs(lat_deg) <= 90.0 and abs(lon_deg) <= 360.0 and math.isfinite(h)):
        raise ValueError(f"latitude {lat_deg}, longitude {lon_deg}, height {h} out of range")
    return geodetic_to_ecef(math.radians(lat_deg), math.radians(lon_deg), h)


def _signed_square(s: float) -> float:
    """RTKLIB writes covariances as signed square roots."""
    return math.copysign(s * s, s)


def _covariance(sd: list[float]) -> Vec:
    """The 3x3 matrix of RTKLIB's six standard deviation columns (sd1 sd2 sd3 sd12 sd23 sd31)."""
    a, b, c = sd[0] ** 2, sd[1] ** 2, sd[2] ** 2
    ab, bc, ca = (_signed_square(v) for v in sd[3:6])
    return np.array([[a, ab, ca], [ab, b, bc], [ca, bc, c]])


def _pos_row(tokens: list[str], layout: _PosLayout) -> PosRecord:
    """One data row; ValueError naming what is wrong."""
    t = _pos_time(tokens, layout)
    rest = tokens[2:]
    if layout.position == "dms":
        if len(rest) < 9:
            raise ValueError(
                f"{len(tokens)} fields, a row of latitude and longitude in d m s has at least 11"
            )
        lat, lon, h = _dms(*rest[0:3]), _dms(*rest[3:6]), float(rest[6])
        rest = rest[7:]
    else:
        if len(rest) < 5:
            raise ValueError(f"{len(tokens)} fields, a row has at least 7")
        lat, lon, h = (float(v) for v in rest[0:3])
        rest = rest[3:]
    ecef = np.array([lat, lon, h]) if layout.position == "xyz" else _geodetic(lat, lon, h)
    if not np.isfinite(ecef).all():
        raise ValueError("non-finite position")
    norm = float(np.linalg.norm(ecef))
    if not EARTH_RADIUS_BOUNDS_M[0] <= norm <= EARTH_RADIUS_BOUNDS_M[1]:
        raise ValueError(f"|ECEF| {norm:.0f} m is not near the Earth's surface")
    quality, n_sats = int(rest[0]), int(rest[1])
    sd = [float(v) for v in rest[2:8]]
    cov = np.zeros((3, 3))
    if len(sd) == 6 and all(math.isfinite(v) for v in sd):
        cov = _covariance(sd)  # ECEF for xyz; north, east, up for the geodetic layouts
        if layout.position != "xyz":
            enu = cov[np.ix_([1, 0, 2], [1, 0, 2])]
            rot = enu_rotation(math.radians(lat), math.radians(lon))  # ECEF -> ENU
            cov = rot.T @ enu @ rot
    return PosRecord(t, ecef, cov, quality, n_sats)


def read_pos(path: str | Path, problems: Problems) -> list[PosRecord]:
    """Every solution of an RTKLIB .pos file, in file order; bad rows counted and skipped.

    Any layout RTKLIB writes: GPST, UTC or JST times as week + seconds or calendar; ECEF,
    latitude / longitude / height in degrees or degrees-minutes-seconds; space or comma separated.
    Heights above the geoid (RTKLIB's `out-height=geodetic`) are refused: a reference needs the
    ellipsoidal height coplane solves for, and converting needs the geoid RTKLIB used."""
    path = Path(path)
    header = ""
    layout: _PosLayout | None = None
    out: list[PosRecord] = []
    for n, line in _lines(path):
        s = line.strip()
        if not s:
            continue
        if s.startswith("%"):
            low = s.lower()
            if "height=" in low and "geodetic" in low:
                raise RecordingError(
                    f"{path}:{n}: heights above the geoid; write the solution with ellipsoidal heights "
                    "(RTKLIB option out-height=ellipsoidal)"
                )
            if "latitude" in low or "x-ecef" in low or "e-baseline" in low or "n-baseline" in low:
                header = s
            continue
        tokens = s.replace(",", " ").split()
        try:
            if layout is None:
                layout = _pos_layout(header, tokens)
            out.append(_pos_row(tokens, layout))
        except (ValueError, IndexError) as exc:
            if layout is None and header:
                raise RecordingError(f"{path}: {exc}") from None
            problems.add(path, n, "malformed-row", f"{exc}: row skipped")
    return out


# --------------------------------------------------------------------------------------------
# Inertial Explorer text export (UrbanNav's ground truth)


def _ie_columns(names_line: str, units_line: str) -> dict[str, tuple[int, int]]:
    """Column name -> (first token, token count): a latitude or longitude whose unit is "D M S"
    takes three tokens of a row."""
    names = names_line.split()
    units = re.findall(r"\(([^)]*)\)", units_line)
    widths = [3 if i < len(units) and "D M S" in units[i].upper() else 1 for i in range(len(names))]
    out: dict[str, tuple[int, int]] = {}
    k = 0
    for name, w in zip(names, widths, strict=True):
        out[name.lower()] = (k, w)
        k += w
    return out


def read_inertial_explorer(path: str | Path, problems: Problems) -> tuple[list[TruthPoint], Counter[int]]:
    """The points of an Inertial Explorer text export (Week, GPSTime, Latitude, Longitude, H-Ell
    columns, a units line under the names) and how many rows had each Q; bad rows counted."""
    path = Path(path)
    cols: dict[str, tuple[int, int]] | None = None
    names = ""
    out: list[TruthPoint] = []
    quality: Counter[int] = Counter()
    for n, line in _lines(path):
        s = line.strip()
        if not s:
            continue
        if not names:
            names = s
            continue
        if cols is None:
            cols = _ie_columns(names, s if s.startswith("(") else "")
            need = [c for c in ("week", "gpstime", "latitude", "longitude", "h-ell") if c not in cols]
            if need:
                raise RecordingError(f"{path}: no column(s) {', '.join(need)} in {names[:120]!r}")
            if s.startswith("("):
                continue  # the units line; without one, this line is the first row
        tokens = s.split()
        try:
            week = int(float(tokens[cols["week"][0]]))
            tow = float(tokens[cols["gpstime"][0]])
            if week < 0 or not 0.0 <= tow < SECONDS_PER_WEEK:
                raise ValueError(f"time {week} {tow} out of range")
            lat = _angle(tokens, cols["latitude"])
            lon = _angle(tokens, cols["longitude"])
            ecef = _geodetic(lat, lon, float(tokens[cols["h-ell"][0]]))
            t = GpsTime(week, tow)
            if out and t <= out[-1].time:
                raise ValueError(f"time {t} is not after the previous row's {out[-1].time}")
            if "q" in cols:
                quality[int(float(tokens[cols["q"][0]]))] += 1
        except (ValueError, IndexError) as exc:
            problems.add(path, n, "malformed-row", f"{exc}: row skipped")
            continue
        out.append(TruthPoint(t, (float(ecef[0]), float(ecef[1]), float(ecef[2]))))
    if cols is None:
        raise RecordingError(f"{path}: a header and no rows")
    return out, quality


def _angle(tokens: list[str], col: tuple[int, int]) -> float:
    first, width = col
    if width == 3:
        return _dms(*tokens[first : first + 3])
    return float(tokens[first])


def read_trajectory(path: str | Path, problems: Problems) -> Trajectory:
    """A reference trajectory from an RTKLIB .pos, an Inertial Explorer export or coplane's own
    truth CSV (`sniff`), points in increasing time.

    An RTKLIB file with fixed solutions is an RTK or PPK reference: only its fixed rows are taken,
    as a float or code row can be metres off and would be scored as the truth. Its rows are sorted
    (RTKLIB writes a backward run last epoch first); a second row at one time is counted and
    skipped."""
    path = Path(path)
    kind = sniff(path)
    if kind == "ie":
        return Trajectory(*read_inertial_explorer(path, problems), kind="Inertial Explorer text")
    if kind == "csv":
        return Trajectory(read_truth(path, problems), kind="coplane truth CSV")
    records = read_pos(path, problems)
    quality = Counter(r.quality for r in records)
    keep = [r for r in records if r.quality == Q_FIX] if Q_FIX in quality else records
    points: list[TruthPoint] = []
    for r in sorted(keep, key=lambda r: r.time):
        if points and r.time == points[-1].time:
            problems.add(path, None, "duplicate-row", f"a second solution at {r.time}: skipped")
            continue
        points.append(TruthPoint(r.time, (float(r.ecef[0]), float(r.ecef[1]), float(r.ecef[2]))))
    return Trajectory(points, quality, left_out=len(records) - len(keep))
