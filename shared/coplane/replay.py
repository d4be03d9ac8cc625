"""The epoch schedule of a replay, shared by the in-process evaluator and the vehicle agents.

A vehicle is live from its first to its last observation epoch. Inside that span it reports at
every nominal epoch (a multiple of the interval), with an empty report where its receiver had no
epoch (an underpass, a dropped epoch), so that in lockstep the server never waits for a message
that will not come and the vehicle still gets a plane and a carried-through position.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Sequence
from typing import TYPE_CHECKING

from coplane.gtime import GpsTime
from coplane.recording.model import ObsEpoch, UwbRange

if TYPE_CHECKING:
    from coplane.recording.reader import Recording


def nominal_grid(first: GpsTime, last: GpsTime, interval_s: float) -> Iterator[GpsTime]:
    t0 = first.round_to(interval_s)
    n = round((last.round_to(interval_s) - t0) / interval_s)
    for k in range(n + 1):
        yield (t0 + k * interval_s).round_to(interval_s)


def vehicle_schedule(epochs: Sequence[ObsEpoch], interval_s: float) -> list[tuple[GpsTime, ObsEpoch | None]]:
    """(nominal time, the receiver epoch or None) for every nominal epoch of the vehicle's span."""
    if not epochs:
        return []
    by_t: dict[GpsTime, ObsEpoch] = {}
    for e in epochs:
        by_t.setdefault(e.time.round_to(interval_s), e)  # the reader already dropped duplicates
    return [(t, by_t.get(t)) for t in nominal_grid(epochs[0].time, epochs[-1].time, interval_s)]


def fleet_id(name: str) -> str:
    """A bus-safe fleet id ([A-Za-z0-9_-], at most 32 chars) from a recording's free-text name."""
    slug = "".join(c if c.isalnum() or c in "-_" else "-" for c in name.strip())
    slug = "-".join(p for p in slug.split("-") if p)[:32].strip("-")
    return slug or "fleet"


def uwb_for_vehicle(
    ranges: Iterable[UwbRange],
    vehicle_id: str,
    times: Iterable[GpsTime],
    interval_s: float,
    tolerance: float = 0.1,
) -> dict[GpsTime, list[UwbRange]]:
    """The ranges `vehicle_id` measured (it is `from_id`), by the nominal epochs it reports at.

    A row belongs to the nearest nominal epoch within `tolerance` x interval (spec); a pair at most
    once per epoch (first row wins). The agent and the in-process evaluator both use this, so
    both send the same ranges.
    """
    wanted = set(times)
    out: dict[GpsTime, list[UwbRange]] = {}
    seen: set[tuple[GpsTime, tuple[str, str]]] = set()
    for r in ranges:
        if r.a != vehicle_id or r.b == vehicle_id:
            continue
        t = r.time.round_to(interval_s)
        if t not in wanted or abs(r.time - t) > tolerance * interval_s or (t, r.pair) in seen:
            continue
        seen.add((t, r.pair))
        out.setdefault(t, []).append(r)
    return out


def first_epoch(recording: Recording) -> GpsTime | None:
    """The fleet's first nominal epoch, reading one epoch per file (shared realtime origin)."""
    from coplane.recording.problems import Problems
    from coplane.recording.rinex_obs import iter_obs

    firsts = []
    for v in recording.manifest.vehicles:
        _, it = iter_obs(v.obs, Problems())
        e = next(it, None)
        if e is not None:
            firsts.append(e.time)
    return min(firsts).round_to(recording.manifest.interval_s) if firsts else None


def base_by_epoch(recording: Recording) -> dict[GpsTime, ObsEpoch]:
    """The reference station's epochs by nominal time (first wins), for DGNSS corrections."""
    out: dict[GpsTime, ObsEpoch] = {}
    for e in recording.base_epochs():
        out.setdefault(e.time.round_to(recording.manifest.interval_s), e)
    return out
