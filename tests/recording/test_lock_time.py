"""The lock time the RTCM 3 and UBX writers put in their logs (`recording.lock_time.LockTimer`)."""

from __future__ import annotations

from coplane.gtime import GpsTime
from coplane.recording.lock_time import LockTimer


def test_lock_time_grows_with_tracking_and_restarts_on_a_gap_or_without_phase() -> None:
    lock = LockTimer()
    t0 = GpsTime(2300, 1000.0)
    assert [lock.ms("G01", t0 + k, True) for k in range(4)] == [0, 1000, 2000, 3000]
    assert lock.ms("G01", t0 + 5, True) == 0  # 2 s gap at a 1-s interval: lock lost
    assert lock.ms("G01", t0 + 6, True) == 1000
    assert lock.ms("G01", t0 + 7, False) == 0  # no carrier phase: no lock
    assert lock.ms("C05", t0 + 7, True) == 0  # each satellite on its own
    assert lock.ms("C05", t0 + 8.5, True) == 1500  # a 1.5-s gap is still within 1.5 intervals
