"""The simulated world: broadcast ephemerides, the epochs, the road and its canyon, the fleet and the base.

Everything here is fixed before the first epoch is simulated, so the per-epoch code
(coplane.sim.epoch) only reads it. The models and their numbers are in docs/simulator.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from coplane.geo import geodetic_to_ecef
from coplane.gnss.ephemeris import select_ephemeris
from coplane.gtime import GpsTime
from coplane.recording.model import NavData
from coplane.recording.problems import Problems
from coplane.recording.rinex_nav import read_nav
from coplane.sim.canyon import Canyon
from coplane.sim.city_world import build_city
from coplane.sim.errors import ReceiverParams, component_rng
from coplane.sim.motion import FleetTrack, simulate_motion
from coplane.sim.road import RaisedProfile, Road, RoadRaise, Sections, enu_to_ecef_curved
from coplane.sim.scenarios import Scenario
from coplane.sim.sky import enu_rotations
from coplane.typing import AnyArray, Mat, Vec

# observation codes per system (pseudorange, Doppler, C/N0); also which systems are simulated
SIGNAL_TYPES = {"G": ("C1C", "D1C", "S1C"), "C": ("C2I", "D2I", "S2I")}


@dataclass
class World:
    """What every epoch shares. Receivers are the vehicles (rows :vehicles) then the base, if any."""

    scenario: Scenario
    vehicles: int
    times: list[GpsTime]  # true GPS time of each epoch
    nav: NavData
    nav_path: Path
    sats: list[str]  # every simulated satellite, sorted
    road: Road
    sections: Sections
    canyon: Canyon
    track: FleetTrack
    origin_lat: float  # rad
    origin_lon: float  # rad
    origin_ecef: Vec
    rot0: Mat  # ENU rows at the origin
    base_ecef: Vec | None

    @property
    def dt(self) -> float:
        return self.scenario.interval_s

    @property
    def n_rx(self) -> int:
        return self.vehicles + (1 if self.base_ecef is not None else 0)

    @property
    def rx_params(self) -> list[ReceiverParams]:
        """Receiver parameters per receiver row."""
        sc = self.scenario
        return [sc.vehicle_receiver] * self.vehicles + (
            [sc.base_receiver] if self.base_ecef is not None else []
        )

    @property
    def groups(self) -> list[tuple[slice, ReceiverParams]]:
        """Receivers come in two groups with their own parameters: vehicles (rows :m) and the base."""
        m = self.vehicles
        groups: list[tuple[slice, ReceiverParams]] = [(slice(0, m), self.scenario.vehicle_receiver)]
        if self.base_ecef is not None:
            groups.append((slice(m, m + 1), self.scenario.base_receiver))
        return groups

    def receivers_at(self, k: int) -> tuple[Mat, Mat]:
        """ECEF positions and velocities of every receiver at epoch k (the base stands still)."""
        pos = self.track.ecef[k]
        vel = self.track.vel_ecef[k]
        if self.base_ecef is not None:
            pos = np.vstack([pos, self.base_ecef[None, :]])
            vel = np.vstack([vel, np.zeros((1, 3))])
        return pos, vel


def _check_window(nav: NavData, sats: list[str], t0: GpsTime, t1: GpsTime) -> None:
    def usable(t: GpsTime) -> int:
        return sum(select_ephemeris(nav, s, t) is not None for s in sats)

    n0, n1 = usable(t0), usable(t1)
    if n1 < n0 or n0 < 8:
        raise ValueError(
            f"time window {t0} .. {t1} leaves the broadcast ephemeris validity "
            f"({n0} satellites usable at the start, {n1} at the end)"
        )


def build_world(
    sc: Scenario,
    vehicles: int,
    duration_s: float,
    seed: int,
    start_offset_s: float = 0.0,
    road_raise: tuple[RoadRaise, ...] = (),
) -> World:
    """Read the navigation file, lay out the road and canyon and drive the fleet (seeded streams).

    `start_offset_s` starts the drive that much after the scenario's start: the same roads under
    another sky (satellite geometry, atmosphere), as a second day's drive would be; the road map
    benchmarks need runs whose GNSS errors are independent. `road_raise` re-surfaces sections.
    """
    if vehicles < 1:
        raise ValueError("at least one vehicle is needed")
    dt = sc.interval_s
    n_ep = round(duration_s / dt)
    if n_ep < 1:
        raise ValueError(f"duration {duration_s} s is shorter than one epoch")
    problems = Problems()
    nav_path = sc.nav_path()
    nav = read_nav(nav_path, problems)
    if problems.total:
        raise ValueError(f"navigation file {nav_path} has {problems.total} problems")
    sats = sorted(s for s in nav.ephemerides if s[0] in SIGNAL_TYPES)
    t0 = GpsTime.from_calendar(*sc.start) + start_offset_s
    times = [t0 + k * dt for k in range(n_ep)]
    _check_window(nav, sats, t0, times[-1])

    rp = sc.road
    origin = (rp.origin_lat_deg, rp.origin_lon_deg, rp.origin_h_m)
    road: Road
    sections: Sections
    canyon: Canyon
    if sc.city is not None:
        if road_raise:
            raise ValueError("road_raise applies to a single-loop scenario, not to the city")
        city = build_city(sc, vehicles, n_ep, seed)
        road, sections, canyon, track = city.road, city.sections, city.canyon, city.track
    else:
        road = Road(rp.waypoints_en, rp.corner_radius_m, rp.lanes, rp.lane_width_m, rp.grade_changes)
        if road_raise:
            road.profile = RaisedProfile(road.profile, road_raise)
        sections = Sections(road.length_m, rp.sections)
        canyon = Canyon(road, sections, sc.canyon, component_rng(seed, "canyon"))
        track = simulate_motion(
            road, sections, sc.motion, vehicles, n_ep, dt, origin, component_rng(seed, "motion")
        )
    origin_ecef = geodetic_to_ecef(
        math.radians(rp.origin_lat_deg), math.radians(rp.origin_lon_deg), rp.origin_h_m
    )
    base_ecef: AnyArray | None = None
    if sc.base is not None:
        b = sc.base
        base_ecef = np.round(
            enu_to_ecef_curved(np.array([b.east_m, b.north_m, b.height_above_origin_m]), *origin), 4
        )
    lat0, lon0 = math.radians(rp.origin_lat_deg), math.radians(rp.origin_lon_deg)
    rot0 = enu_rotations(np.array([lat0]), np.array([lon0]))[0]
    return World(
        scenario=sc,
        vehicles=vehicles,
        times=times,
        nav=nav,
        nav_path=nav_path,
        sats=sats,
        road=road,
        sections=sections,
        canyon=canyon,
        track=track,
        origin_lat=lat0,
        origin_lon=lon0,
        origin_ecef=origin_ecef,
        rot0=rot0,
        base_ecef=base_ecef,
    )
