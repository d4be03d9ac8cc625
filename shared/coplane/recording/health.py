"""How much of a recording was usable: the figure behind `--strict` (docs/recording-format.md).

A run that reads a recording with a few bad lines is normal and prints its problem count. A run
where many records were bad, or that positioned nothing, usually means the wrong file or a broken
conversion: the commands warn, and with `--strict` exit non-zero so a pipeline stops there.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass

from coplane.gtime import GpsTime, calendar_day, calendar_span
from coplane.recording.reader import Recording

MAX_PROBLEM_SHARE = 0.05  # above this share of records with a problem, the input is suspect
EPHEMERIS_REACH_S = 4 * 3600.0  # an ephemeris this far from every observation cannot serve any


@dataclass(frozen=True)
class InputHealth:
    """Records kept (observation epochs of the vehicles and the base, UWB rows, truth rows) and
    problems found. One problem is counted against one record: an upper bound on what was lost."""

    records: int
    problems: int
    nav_gap: str | None = None  # the ephemerides do not cover the observations: what to look at

    @property
    def problem_share(self) -> float:
        total = self.records + self.problems
        return self.problems / total if total else 0.0


def input_health(rec: Recording) -> InputHealth:
    """Read every file of the recording (cached by the reader) and count what it kept."""
    records = sum(len(rec.vehicle_epochs(v.id)) + len(rec.truth(v.id)) for v in rec.manifest.vehicles)
    records += len(rec.base_epochs()) + len(rec.uwb())
    return InputHealth(records, rec.problems.total, nav_gap(rec))


def nav_gap(rec: Recording) -> str | None:
    """A sentence naming the nav files when their ephemerides are nowhere near the observations
    (a week-old brdc file is the usual cause of a run that positions nothing)."""
    times = [ep.time for v in rec.manifest.vehicles for ep in rec.vehicle_epochs(v.id)]
    if not times:
        return None
    return ephemeris_gap(rec, min(times), max(times))


def ephemeris_gap(rec: Recording, first: GpsTime, last: GpsTime) -> str | None:
    """`nav_gap` for observations spanning `first` .. `last`, when a caller knows the span
    already (`coplane recording init` has read every file once): the navigation files only.

    It names the days the ephemerides are from, most first, and how far the nearest is: a
    navigation file often holds a stray record of another week (KLT's HKSC file has one GPS
    ephemeris 30 weeks older than the rest), so its first and last toe would span the
    observations and say nothing of why none serves them."""
    toes = [e.toe for ephs in rec.nav.ephemerides.values() for e in ephs]
    if not toes:
        return None
    nearest = min(abs(t - toe) for toe in toes for t in (first, last))
    if nearest <= EPHEMERIS_REACH_S:
        return None
    listed = ephemeris_days(toes)
    files = ", ".join(str(f) for f in rec.manifest.nav_files)
    return (
        f"the ephemerides in {files} are from {listed} (GPS time; how many each day), the nearest "
        f"{_duration(nearest)} from the observations, which are from {calendar_span(first, last)}"
    )


def ephemeris_days(toes: Sequence[GpsTime], most: int = 3) -> str:
    """The days (GPS time) ephemerides are from, with how many each, most first: '2021-06-10
    (134), 2021-06-09 (25), 2020-11-10 (1)'. A first and last toe would span the stray record of
    another week that navigation files often hold, and seem to cover months."""
    days = Counter(calendar_day(toe) for toe in toes).most_common()
    listed = ", ".join(f"{d} ({n})" for d, n in days[:most])
    return listed + (f" and {len(days) - most} other day(s)" if len(days) > most else "")


def _duration(seconds: float) -> str:
    return f"{seconds / 86400.0:.1f} days" if seconds >= 2 * 86400.0 else f"{seconds / 3600.0:.1f} h"


def health_warnings(health: InputHealth, fixes: int) -> list[str]:
    """What a user must be told about the input: no fix at all, or too many bad records."""
    out = []
    if fixes == 0:
        why = f": {health.nav_gap}" if health.nav_gap else ""
        out.append(f"no position was computed from this recording{why}")
    if health.problem_share > MAX_PROBLEM_SHARE:
        out.append(
            f"{health.problems} input problems against {health.records} records kept "
            f"({100 * health.problem_share:.1f} % > {100 * MAX_PROBLEM_SHARE:.0f} %)"
        )
    return out
