"""Conventions every broadcast-message format shares (RTCM 3 1019/1042, UBX RXM-SFRBX): the URA
table that turns an accuracy in metres into an index and back, and the rules that turn a truncated
week number or a bare time of week into a full GPS time.

They belong to the data formats, not to the GNSS models: gnss/ephemeris.py takes the URA table from
here to quantise the ephemeris variance as RTKLIB does.
"""

from __future__ import annotations

import datetime as _dt

from coplane.gtime import SECONDS_PER_WEEK, GpsTime

# URA table (IS-GPS-200 20.3.3.3.1.1), metres. RTKLIB maps a broadcast accuracy in metres to the
# first index whose value is >= it, and uses that value squared as the ephemeris variance.
URA_TABLE_M: tuple[float, ...] = (
    2.4, 3.4, 4.85, 6.85, 9.65, 13.65, 24.0, 48.0, 96.0, 192.0, 384.0, 768.0, 1536.0, 3072.0, 6144.0,
)  # fmt: skip
MAX_TOW_JUMP_S = SECONDS_PER_WEEK / 2


def ura_index(sva_m: float) -> int:
    """The URA index whose bin holds an accuracy in metres (15: unknown / beyond the table)."""
    for i, v in enumerate(URA_TABLE_M):
        if sva_m <= v:
            return i
    return 15


def ura_value(index: int) -> float:
    """The accuracy in metres an index stands for: the upper bound of its bin (RTKLIB's reading)."""
    return URA_TABLE_M[index] if index < len(URA_TABLE_M) else 2.0 * URA_TABLE_M[-1]


def resolve_week(week_mod: int, bits: int, reference_week: int) -> int:
    """The full week whose low `bits` bits are `week_mod`, nearest to `reference_week`."""
    cycle = 1 << bits
    base = reference_week - (reference_week % cycle) + week_mod
    return min((base - cycle, base, base + cycle), key=lambda w: abs(w - reference_week))


def nearest_week(tow_s: float, reference: GpsTime) -> GpsTime:
    """The instant with this time of week nearest to `reference` (within half a week)."""
    t = GpsTime(reference.week, tow_s)
    d = t - reference
    if d > MAX_TOW_JUMP_S:
        return GpsTime(reference.week - 1, tow_s)
    if d < -MAX_TOW_JUMP_S:
        return GpsTime(reference.week + 1, tow_s)
    return t


def today() -> GpsTime:
    """Now, as GPST to within the leap seconds (only used to place 10-bit weeks)."""
    now = _dt.datetime.now(_dt.UTC)
    return GpsTime.from_calendar(now.year, now.month, now.day, now.hour, now.minute, now.second)
