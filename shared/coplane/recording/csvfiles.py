"""uwb.csv and truth/<id>.csv: readers that skip and report bad rows, and deterministic writers.

Columns are found by header name, so extra columns (truth velocity, attitude, sigmas) are
ignored and column order is free; the header itself is required (a file without one is not
usable and raises RecordingError). Every bad row is reported with file:line and skipped:
malformed or unparseable rows, NaN, absurd values, unknown vehicle ids, non-monotonic times and
duplicate ranges of one pair at one time tag. Nothing is repaired or interpolated.
"""

from __future__ import annotations

import csv
import math
import re
from collections.abc import Collection, Iterable, Iterator
from pathlib import Path

from coplane.gtime import SECONDS_PER_WEEK, GpsTime
from coplane.recording.model import TruthPoint, UwbRange
from coplane.recording.problems import Problems, RecordingError

UWB_COLUMNS = ("gps_week", "tow_s", "from_id", "to_id", "range_m")
TRUTH_COLUMNS = ("gps_week", "tow_s", "x_m", "y_m", "z_m")
ENVIRONMENT_LABEL = re.compile(r"[A-Za-z][A-Za-z0-9_-]{0,31}")  # optional truth column, e.g. "deep"
DEFAULT_MAX_UWB_RANGE_M = 10_000.0  # when the manifest gives no max_range_m
EARTH_RADIUS_BOUNDS_M = (6.0e6, 7.0e6)  # |ECEF| of a point near the surface (incl. aircraft)


class RowError(ValueError):
    """A bad row: `kind` (a problems slug) and the reason."""

    def __init__(self, kind: str, reason: str) -> None:
        super().__init__(reason)
        self.kind = kind


def _rows(path: Path, required: tuple[str, ...]) -> Iterator[tuple[int, dict[str, str], str | None]]:
    """(line number, {column: text}, error) per data row; RecordingError if the header is unusable."""
    try:
        f = path.open("r", encoding="utf-8", errors="replace", newline="")
    except OSError as exc:
        raise RecordingError(f"{path}: cannot read ({exc.strerror or exc})") from exc
    with f:
        reader = csv.reader(f)
        header: list[str] | None = None
        for row in reader:
            if not any(c.strip() for c in row):
                continue
            if header is None:
                header = [c.strip().lower() for c in row]
                missing = [c for c in required if c not in header]
                if missing:
                    raise RecordingError(
                        f"{path}:{reader.line_num}: header lacks column(s) {', '.join(missing)} "
                        f"(expected {','.join(required)})"
                    )
                continue
            if len(row) != len(header):
                yield reader.line_num, {}, f"{len(row)} fields, header has {len(header)}"
                continue
            yield reader.line_num, dict(zip(header, (c.strip() for c in row), strict=True)), None
        if header is None:
            raise RecordingError(f"{path}: empty file (a header {','.join(required)} is required)")


def _time(row: dict[str, str]) -> GpsTime:
    try:
        week = int(row["gps_week"])
        tow = float(row["tow_s"])
    except ValueError:
        raise RowError("malformed-row", f"unreadable time {row['gps_week']!r},{row['tow_s']!r}") from None
    if week < 0 or not (0.0 <= tow < SECONDS_PER_WEEK):
        raise RowError("malformed-row", f"time {week},{tow} out of range")
    return GpsTime(week, tow)


def _float(row: dict[str, str], key: str) -> float:
    try:
        v = float(row[key])
    except ValueError:
        raise RowError("malformed-row", f"{key}: unreadable number {row[key]!r}") from None
    if not math.isfinite(v):
        raise RowError("nan-value", f"{key}: {row[key]!r}")
    return v


def uwb_range(row: dict[str, str], vehicle_ids: Collection[str], limit_m: float) -> UwbRange:
    """One uwb.csv row (or a live UWB line, docs/live.md) as a range; a `RowError` (kind, reason)
    names what is wrong with it."""
    t = _time(row)
    a, b = row["from_id"], row["to_id"]
    for vid in (a, b):
        if vid not in vehicle_ids:
            raise RowError("unknown-id", f"vehicle id {vid!r} is not in the manifest")
    if a == b:
        raise RowError("malformed-row", f"range from {a!r} to itself")
    r = _float(row, "range_m")
    if not 0.0 < r <= limit_m:
        raise RowError("absurd-value", f"range {r} m outside (0, {limit_m}] m")
    return UwbRange(t, a, b, r)


def read_uwb(
    path: str | Path,
    problems: Problems,
    vehicle_ids: set[str],
    max_range_m: float | None = None,
) -> list[UwbRange]:
    """Inter-vehicle ranges in file order; bad rows reported and skipped."""
    path = Path(path)
    limit = DEFAULT_MAX_UWB_RANGE_M if max_range_m is None else max_range_m
    out: list[UwbRange] = []
    seen: set[tuple[GpsTime, tuple[str, str]]] = set()
    last: GpsTime | None = None
    for lineno, row, error in _rows(path, UWB_COLUMNS):
        try:
            if error is not None:
                raise RowError("malformed-row", error)
            u = uwb_range(row, vehicle_ids, limit)
            t = u.time
            if last is not None and t < last:
                raise RowError("non-monotonic-time", f"time {t} is before the previous row's {last}")
            if (t, u.pair) in seen:
                raise RowError("duplicate-row", f"pair {u.pair} already has a range at {t}")
        except RowError as exc:
            problems.add(path, lineno, exc.kind, f"{exc}: row skipped")
            continue
        seen.add((t, u.pair))
        last = t
        out.append(u)
    return out


def read_truth(path: str | Path, problems: Problems) -> list[TruthPoint]:
    """Reference ECEF positions in strictly increasing time; bad rows reported and skipped."""
    path = Path(path)
    out: list[TruthPoint] = []
    last: GpsTime | None = None
    lo, hi = EARTH_RADIUS_BOUNDS_M
    for lineno, row, error in _rows(path, TRUTH_COLUMNS):
        try:
            if error is not None:
                raise RowError("malformed-row", error)
            t = _time(row)
            xyz = (_float(row, "x_m"), _float(row, "y_m"), _float(row, "z_m"))
            norm = math.sqrt(xyz[0] ** 2 + xyz[1] ** 2 + xyz[2] ** 2)
            if not lo <= norm <= hi:
                raise RowError("absurd-value", f"|ECEF| {norm:.0f} m is not near the Earth's surface")
            if last is not None and t <= last:
                raise RowError("non-monotonic-time", f"time {t} is not after the previous row's {last}")
        except RowError as exc:
            problems.add(path, lineno, exc.kind, f"{exc}: row skipped")
            continue
        last = t
        env = row.get("environment") or row.get("section") or ""
        if env and not ENVIRONMENT_LABEL.fullmatch(env):
            problems.add(
                path,
                lineno,
                "malformed-value",
                f"environment {env[:40]!r} is not a label: row kept without it",
            )
            env = ""
        out.append(TruthPoint(t, xyz, env))
    return out


def _tow(tow: float) -> str:
    """Seconds of week with up to 7 decimals (RINEX epoch resolution), at least one."""
    s = f"{tow:.7f}".rstrip("0")
    return s + "0" if s.endswith(".") else s


def _write_lines(path: str | Path, header: tuple[str, ...], rows: Iterable[str]) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(",".join(header) + "\n" + "".join(r + "\n" for r in rows), encoding="utf-8", newline="\n")
    return path


def write_uwb(path: str | Path, ranges: Iterable[UwbRange]) -> Path:
    """uwb.csv, ranges to 0.1 mm, rows in the given order."""
    return _write_lines(
        path, UWB_COLUMNS, (f"{u.time.week},{_tow(u.time.tow)},{u.a},{u.b},{u.range_m:.4f}" for u in ranges)
    )


def write_truth(path: str | Path, points: Iterable[TruthPoint]) -> Path:
    """truth/<id>.csv, positions to 0.1 mm; with an `environment` column when any point has a label,
    so that a copy keeps the per-environment accuracy of the original."""
    rows = list(points)
    if not any(p.environment for p in rows):
        return _write_lines(
            path,
            TRUTH_COLUMNS,
            (
                f"{p.time.week},{_tow(p.time.tow)},{p.ecef_m[0]:.4f},{p.ecef_m[1]:.4f},{p.ecef_m[2]:.4f}"
                for p in rows
            ),
        )
    return _write_lines(
        path,
        (*TRUTH_COLUMNS, "environment"),
        (
            f"{p.time.week},{_tow(p.time.tow)},{p.ecef_m[0]:.4f},{p.ecef_m[1]:.4f},{p.ecef_m[2]:.4f},{p.environment}"
            for p in rows
        ),
    )
