"""GPS time arithmetic against calendar facts and BDT offsets."""

from hypothesis import given
from hypothesis import strategies as st

from coplane.gtime import GpsTime, bdt_to_gpst, gpst_to_bdt


def test_calendar_known_dates() -> None:
    # 2024-06-24 08:20:00 GPST (MatRTKLIB Nagoya set) is GPS week 2320, Monday.
    t = GpsTime.from_calendar(2024, 6, 24, 8, 20, 0.0)
    assert (t.week, t.tow) == (2320, 86400 + 8 * 3600 + 20 * 60)
    assert GpsTime.from_calendar(1980, 1, 6) == GpsTime(0, 0.0)
    assert t.to_calendar()[:5] == (2024, 6, 24, 8, 20)


def test_week_rollover_and_difference() -> None:
    a = GpsTime(2000, 604799.5)
    b = a + 1.0
    assert (b.week, b.tow) == (2001, 0.5)
    assert b - a == 1.0
    assert (a + -604800.0) == GpsTime(1999, 604799.5)


def test_bdt_round_trip_and_offset() -> None:
    # BDT epoch 2006-01-01 00:00:00 BDT = GPS week 1356, tow 14 s.
    t = bdt_to_gpst(0, 0.0)
    assert (t.week, t.tow) == (1356, 14.0)
    assert gpst_to_bdt(t) == (0, 0.0)


@given(st.integers(0, 3000), st.floats(0, 604799.999), st.floats(-1e6, 1e6))
def test_add_sub_inverse(week: int, tow: float, dt: float) -> None:
    t = GpsTime(week, tow)
    assert abs(((t + dt) - t) - dt) < 1e-6
