"""How long each satellite's carrier has been tracked, for the logs coplane writes.

RTCM 3 MSM messages (lock-time indicator) and UBX RXM-RAWX (locktime) carry it; an `ObsEpoch`
does not, so the writers (`rtcm3.write_rtcm3`, `ubx.write_ubx`) infer it from the observations:
the time since the satellite was first seen with a carrier phase, restarted by a gap of more than
1.5 epoch intervals (a loss of lock). pyrtcm and pyubx2 encode the field but leave its value to
the caller, hence this small class.
"""

from __future__ import annotations

import math

from coplane.gtime import GpsTime


class LockTimer:
    """Lock time per satellite over the epochs of one log, in the order they are written."""

    def __init__(self) -> None:
        self._since: dict[str, GpsTime] = {}
        self._last: dict[str, GpsTime] = {}
        self._interval = math.inf  # the shortest gap seen between two epochs of a satellite

    def ms(self, sat: str, t: GpsTime, has_phase: bool) -> int:
        """Milliseconds `sat` has been tracked at `t` (0 when it has no phase or was not seen for
        more than 1.5 intervals)."""
        last = self._last.get(sat)
        if last is not None:
            self._interval = min(self._interval, max(t - last, 1e-3))
        if last is None or not has_phase or t - last > 1.5 * self._interval:
            self._since[sat] = t
        self._last[sat] = t
        return round((t - self._since[sat]) * 1000.0)
