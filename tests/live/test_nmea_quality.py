"""NMEA output's fix quality per vehicle and epoch (`coplane.live.nmea_out`): GGA quality and RMC
mode say whether that epoch had the base's corrections, not whether the fleet has a base, and an
epoch the graph carried without a GNSS fix is "estimated" (the .pos Q rule, `pos_quality`)."""

from __future__ import annotations

import pytest
from pynmeagps import NMEAReader
from support.api import T0, ecef_at, solution, vehicle_state

from coplane.evaluate.solution_files import pos_quality
from coplane.live.nmea_out import NmeaFormatter
from coplane.recording.trajectories import Q_DGPS, Q_DR, Q_SINGLE


@pytest.mark.parametrize(
    ("has_fix", "age", "gga_quality", "rmc_mode", "q"),
    [(True, 1.2, 2, "D", Q_DGPS), (True, None, 1, "A", Q_SINGLE), (False, 1.2, 6, "E", Q_DR)],
)
def test_quality_follows_the_epoch(
    has_fix: bool, age: float | None, gga_quality: int, rmc_mode: str, q: int
) -> None:
    v = vehicle_state("a", ecef_at(10.0, 5.0)).model_copy(
        update={"has_gnss_fix": has_fix, "dgnss_age_s": age}
    )
    raw = NmeaFormatter().sentences(solution(1, T0, [v]))["a"]
    msgs = {m.msgID: m for m in (NMEAReader.parse(line + b"\r\n") for line in raw.split(b"\r\n") if line)}
    assert msgs["GGA"].quality == gga_quality and msgs["RMC"].posMode == rmc_mode
    assert msgs["GGA"].diffAge == ("" if age is None else age)
    assert pos_quality(has_fix, age) == q
