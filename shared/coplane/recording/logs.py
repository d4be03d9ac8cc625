"""Receiver logs (UBX, RTCM 3) read once for both things they hold: observations and ephemerides.

A u-blox or RTCM 3 log usually carries a receiver's raw observations and the broadcast
ephemerides it decoded. A recording then names the same file as a vehicle's observations and as
a navigation source, and `coplane recording init` asks it both. Reading it once counts its
damage (garbled frames) once, as it is in the file, and halves the parse of a long log.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

from coplane.gtime import GpsTime
from coplane.recording.compressed import file_format
from coplane.recording.model import NavData, ObsEpoch, ObsHeader
from coplane.recording.problems import Problems
from coplane.recording.rinex_obs import SignalCodes
from coplane.recording.rtcm3 import Rtcm3Log, parse_rtcm3
from coplane.recording.sfrbx import read_sfrbx_nav
from coplane.recording.ubx import UbxLog, parse_ubx


def parse_log(
    path: Path, problems: Problems, signals: Mapping[str, SignalCodes] | None = None
) -> UbxLog | Rtcm3Log:
    """A receiver log read once, by the format its name says (`compressed.file_format`)."""
    if file_format(path) == "ubx":
        return parse_ubx(path, problems, signals)
    return parse_rtcm3(path, problems, signals)


def log_observations(
    log: UbxLog | Rtcm3Log, reference: GpsTime | None = None
) -> tuple[ObsHeader, list[ObsEpoch]]:
    """A parsed log's epochs (`reference`: where RTCM 3's week-less epochs are placed)."""
    return log.observations() if isinstance(log, UbxLog) else log.observations(reference)


def log_navigation(log: UbxLog | Rtcm3Log, problems: Problems) -> NavData:
    """A parsed log's broadcast ephemerides (UBX: decoded from its RXM-SFRBX subframes, whose
    problems go to `problems`)."""
    if isinstance(log, UbxLog):
        return read_sfrbx_nav(log.path, problems, frames=log.sfrbx)
    return log.navigation()


class LogCache:
    """Parsed logs kept until each use a recording has for them (its navigation, a receiver's
    observations) has taken them, then dropped: a day-long log is not held twice in memory."""

    def __init__(
        self, problems: Problems, signals: Mapping[str, SignalCodes] | None, uses: Mapping[Path, int]
    ) -> None:
        self._problems, self._signals = problems, signals
        self._uses = dict(uses)  # path -> how many uses are still to come
        self._logs: dict[Path, UbxLog | Rtcm3Log] = {}

    def take(self, path: Path) -> UbxLog | Rtcm3Log:
        """`path` parsed (once for all its uses)."""
        log = self._logs.get(path)
        if log is None:
            log = parse_log(path, self._problems, self._signals)
        left = self._uses.get(path, 1) - 1
        self._uses[path] = left
        if left > 0:
            self._logs[path] = log
        else:
            self._logs.pop(path, None)
        return log
