"""What a simulation produced, in memory: written by coplane.sim.write, inspected by tests and tools."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from coplane.gtime import GpsTime
from coplane.recording.model import NavData, ObsEpoch, UwbRange
from coplane.sim.canyon import Canyon
from coplane.sim.diagnostics import Diagnostics
from coplane.sim.motion import FleetTrack
from coplane.sim.road import Road, Sections
from coplane.sim.scenarios import Scenario
from coplane.typing import Vec


@dataclass
class SimResult:
    """Everything a simulation produced, in memory (write it with `write_recording`)."""

    scenario: Scenario
    seed: int
    times: list[GpsTime]  # true GPS time of each epoch
    vehicle_ids: list[str]
    track: FleetTrack
    road: Road
    sections: Sections
    canyon: Canyon
    nav: NavData
    nav_path: Path
    vehicle_obs: dict[str, list[ObsEpoch]]
    base_obs: list[ObsEpoch]
    base_ecef: Vec | None
    uwb: list[UwbRange]
    diagnostics: Diagnostics | None = None
    uwb_kinds: list[int] = field(default_factory=list)  # 0 LOS, 1 body, 2 building per uwb row
