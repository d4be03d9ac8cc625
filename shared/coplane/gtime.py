"""GPS time as (week, time of week).

Why not a float of seconds since 1980: at ~1.4e9 s a double resolves ~0.2 us, which is about a
millimetre of satellite motion. Week + TOW keeps nanoseconds and is what RINEX, RTKLIB and the
truth CSVs use. BeiDou time (BDT) is GPST - 14 s with weeks counted from 2006-01-01.
"""

from __future__ import annotations

import datetime as _dt
import math
from dataclasses import dataclass

SECONDS_PER_WEEK = 604800.0
GPS_EPOCH = _dt.datetime(1980, 1, 6)
BDT_MINUS_GPST_S = -14.0
BDS_WEEK_OFFSET = 1356  # BDT week 0 starts at GPS week 1356 (2006-01-01 00:00:00 BDT)


@dataclass(frozen=True, order=True, slots=True)
class GpsTime:
    """A GPS-time instant; `tow` is normalised to [0, 604800)."""

    week: int
    tow: float

    def __post_init__(self) -> None:
        if not (math.isfinite(self.tow)):
            raise ValueError(f"time of week is not finite: {self.tow!r}")
        if self.tow < 0.0 or self.tow >= SECONDS_PER_WEEK:
            shift = math.floor(self.tow / SECONDS_PER_WEEK)
            object.__setattr__(self, "week", self.week + shift)
            object.__setattr__(self, "tow", self.tow - shift * SECONDS_PER_WEEK)

    def __add__(self, seconds: float) -> GpsTime:
        return GpsTime(self.week, self.tow + float(seconds))

    def __sub__(self, other: GpsTime) -> float:  # type: ignore[override]
        """Seconds from `other` to `self` (exact to the nanosecond across week rollovers)."""
        return (self.week - other.week) * SECONDS_PER_WEEK + (self.tow - other.tow)

    @property
    def seconds(self) -> float:
        """Seconds since the GPS epoch (for keys and plotting, not for precise differences)."""
        return self.week * SECONDS_PER_WEEK + self.tow

    @classmethod
    def from_seconds(cls, seconds: float) -> GpsTime:
        week = int(seconds // SECONDS_PER_WEEK)
        return cls(week, seconds - week * SECONDS_PER_WEEK)

    @classmethod
    def from_calendar(
        cls, year: int, month: int, day: int, hour: int = 0, minute: int = 0, second: float = 0.0
    ) -> GpsTime:
        """Calendar date in the GPS time scale (as written in RINEX epoch lines)."""
        whole = math.floor(second)
        d = _dt.datetime(year, month, day, hour, minute, whole) - GPS_EPOCH
        total_days = d.days
        week, dow = divmod(total_days, 7)
        return cls(week, dow * 86400.0 + d.seconds + (second - whole))

    def to_calendar(self) -> tuple[int, int, int, int, int, float]:
        whole = math.floor(self.tow)
        t = GPS_EPOCH + _dt.timedelta(weeks=self.week, seconds=whole)
        return (t.year, t.month, t.day, t.hour, t.minute, t.second + (self.tow - whole))

    def round_to(self, interval_s: float) -> GpsTime:
        """Nearest multiple of `interval_s` (used to group epochs of different receivers)."""
        return GpsTime(self.week, round(self.tow / interval_s) * interval_s)

    def __str__(self) -> str:
        return f"{self.week}:{self.tow:.3f}"


def bdt_to_gpst(week_bdt: int, sow_bdt: float) -> GpsTime:
    """BeiDou week/second-of-week to GPS time."""
    return GpsTime(week_bdt + BDS_WEEK_OFFSET, sow_bdt - BDT_MINUS_GPST_S)


def gpst_to_bdt(t: GpsTime) -> tuple[int, float]:
    """GPS time to BeiDou week and second of week."""
    b = t + BDT_MINUS_GPST_S
    return b.week - BDS_WEEK_OFFSET, b.tow


# GPS - UTC in whole seconds from each UTC date on (IERS Bulletin C; GPS time has no leap seconds).
# A date after the last entry keeps its offset: add the next leap second here when IERS announces it.
_LEAP_SECONDS: tuple[tuple[_dt.datetime, int], ...] = tuple(
    (_dt.datetime(*d), n)  # type: ignore[misc]
    for d, n in (
        ((1981, 7, 1), 1), ((1982, 7, 1), 2), ((1983, 7, 1), 3), ((1985, 7, 1), 4), ((1988, 1, 1), 5),
        ((1990, 1, 1), 6), ((1991, 1, 1), 7), ((1992, 7, 1), 8), ((1993, 7, 1), 9), ((1994, 7, 1), 10),
        ((1996, 1, 1), 11), ((1997, 7, 1), 12), ((1999, 1, 1), 13), ((2006, 1, 1), 14), ((2009, 1, 1), 15),
        ((2012, 7, 1), 16), ((2015, 7, 1), 17), ((2017, 1, 1), 18),
    )
)  # fmt: skip


def gps_minus_utc_s(t: GpsTime) -> int:
    """Leap seconds between GPS time and UTC at `t`."""
    gps = GPS_EPOCH + _dt.timedelta(weeks=t.week, seconds=t.tow)
    n = 0
    for start_utc, leap in _LEAP_SECONDS:
        if gps - _dt.timedelta(seconds=leap) >= start_utc:
            n = leap
    return n


def gpst_to_utc(t: GpsTime) -> _dt.datetime:
    """UTC of a GPS-time instant (naive datetime, microseconds): what NMEA and most tools print."""
    return GPS_EPOCH + _dt.timedelta(weeks=t.week, seconds=t.tow - gps_minus_utc_s(t))


def calendar_day(t: GpsTime) -> str:
    """'2021-06-10': the GPS-time date of `t`."""
    y, m, d, *_ = t.to_calendar()
    return f"{y:04d}-{m:02d}-{d:02d}"


def calendar_span(first: GpsTime, last: GpsTime) -> str:
    """'2021-05-17 02:33:13 .. 02:46:19' (GPS time; the second date only when it differs): what a
    user compares with a log's name or a calendar, where week and seconds say little."""

    def clock(t: GpsTime) -> str:
        *_, hh, mm, ss = t.to_calendar()
        return f"{hh:02d}:{mm:02d}:{int(ss):02d}"

    tail = clock(last) if calendar_day(last) == calendar_day(first) else f"{calendar_day(last)} {clock(last)}"
    return f"{calendar_day(first)} {clock(first)} .. {tail}"
