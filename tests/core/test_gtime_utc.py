"""GPS time to UTC (leap seconds), as NMEA output prints it."""

from __future__ import annotations

import datetime as dt

from coplane.gtime import GpsTime, gps_minus_utc_s, gpst_to_utc


def test_leap_seconds_at_known_dates() -> None:
    assert gps_minus_utc_s(GpsTime.from_calendar(1980, 1, 6, 0, 0, 0.0)) == 0
    assert gps_minus_utc_s(GpsTime.from_calendar(2016, 12, 31, 12, 0, 0.0)) == 17
    assert gps_minus_utc_s(GpsTime.from_calendar(2024, 6, 24, 8, 10, 0.0)) == 18
    assert gpst_to_utc(GpsTime.from_calendar(2024, 6, 24, 8, 10, 0.5)) == dt.datetime(
        2024, 6, 24, 8, 9, 42, 500000
    )
    # the first GPS second after the 2017 leap second is UTC midnight
    assert gpst_to_utc(GpsTime.from_calendar(2017, 1, 1, 0, 0, 18.0)) == dt.datetime(2017, 1, 1)
