"""Named simulation scenarios. Every number the simulator uses is a field of these dataclasses.

* `urban-loop` (default): a 3.9 km circuit in Zhongguancun, Beijing (the paper's test area,
  Section V), two lanes one way, six turns; open-sky park, medium and deep canyons, a crest
  and sag vertical curves, 3-5 % grades and an underpass; base station in the park.
* `open-sky`: the same road without buildings or underpass (control: only atmosphere,
  orbit/clock, clock, multipath and noise remain).
* `dense-urban`: the same road lined with taller buildings closer to the road, a second
  underpass and stronger multipath (hard case).
* `city`: load generation: a street grid a few km wide whose loops (rectangles of 1-4 blocks)
  share and cross streets, vehicles in platoons of 2-6 per loop (coplane.sim.city); the base
  stands in the middle block. Only `road`'s origin and lanes apply to it.

The time window 2024-06-24 08:10 GPST lies inside the validity of the bundled broadcast
ephemerides (GPS and BeiDou usable 08:00-10:00 GPST, see coplane/data/nav/README.md).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

from coplane.sim.canyon import BuildingParams, CanyonParams, UnderpassParams
from coplane.sim.city import CityParams
from coplane.sim.errors import (
    CommonModeParams,
    IonoParams,
    MultipathParams,
    NlosParams,
    ReceiverParams,
    TropoParams,
    base_receiver_params,
)
from coplane.sim.motion import MotionParams
from coplane.sim.road import GradeChange
from coplane.sim.uwb import UwbParams

BUNDLED_NAV = "matrtklib_nagoya_20240624.nav"


def bundled_nav_path() -> Path:
    """The real RINEX 3.04 navigation file shipped with the package (MIT, see its README)."""
    return Path(str(resources.files("coplane") / "data" / "nav" / BUNDLED_NAV))


@dataclass(frozen=True)
class RoadParams:
    """Plan view (local East-North metres about the origin), lanes and vertical profile.

    The circuit's legs, in driving order (counter-clockwise, five left turns and one right):
    A(0,0) -> B(1300,0) -> C(1300,700) -> D(650,700) -> E(650,500) -> F(0,500) -> A. With 25 m
    fillets the centreline is 3935.6 m. Arc length s starts at A's exit tangent, heading east.
    """

    origin_lat_deg: float = 39.9800  # Zhongguancun, Haidian, Beijing
    origin_lon_deg: float = 116.3100
    origin_h_m: float = 40.0  # ellipsoidal height (about 50 m above sea level, geoid -10 m)
    waypoints_en: tuple[tuple[float, float], ...] = (
        (0.0, 0.0),
        (1300.0, 0.0),
        (1300.0, 700.0),
        (650.0, 700.0),
        (650.0, 500.0),
        (0.0, 500.0),
    )
    corner_radius_m: float = 25.0
    lanes: int = 2
    lane_width_m: float = 3.5
    # grade changes: +4 % up, a crest to -5 % (80 m curve: one 50 m plane does not fit), back to
    # flat; a +3 % climb on leg B-C; the underpass dip (-4.5 %/+4.5 %) on leg C-D; a -3.5 %
    # descent on leg E-F whose end is placed so that the loop closes.
    grade_changes: tuple[GradeChange, ...] = (
        GradeChange(330.0, 0.04, 60.0),
        GradeChange(640.0, -0.05, 80.0),
        GradeChange(850.0, 0.0, 60.0),
        GradeChange(1450.0, 0.03, 50.0),
        GradeChange(1700.0, 0.0, 50.0),
        GradeChange(2110.0, -0.045, 40.0),
        GradeChange(2240.0, 0.0, 40.0),
        GradeChange(2370.0, 0.045, 40.0),
        GradeChange(2500.0, 0.0, 40.0),
        GradeChange(2900.0, -0.035, 50.0),
        GradeChange(3200.0, 0.0, 50.0),
    )
    # (start s, kind); the underpass deck spans 2260-2350 m (90 m: 8-11 s at 8.2-11 m/s)
    sections: tuple[tuple[float, str], ...] = (
        (0.0, "open"),
        (350.0, "medium"),
        (800.0, "deep"),
        (1600.0, "medium"),
        (2260.0, "underpass"),
        (2350.0, "medium"),
        (2850.0, "deep"),
        (3250.0, "medium"),
        (3446.0, "open"),
    )


def _urban_buildings() -> dict[str, BuildingParams]:
    """Zhongguancun-like blocks: 4-8 storey along medium streets, 40-100 m towers in the core."""
    return {
        "open": BuildingParams(height_m=(3.0, 9.0), setback_m=(28.0, 45.0), fill=0.25),
        "medium": BuildingParams(height_m=(10.0, 25.0), setback_m=(16.0, 24.0), fill=0.75),
        "deep": BuildingParams(height_m=(30.0, 70.0), setback_m=(18.0, 25.0), fill=0.85, gap_m=(5.0, 20.0)),
    }


@dataclass(frozen=True)
class BaseStationParams:
    """DGNSS reference station in open sky near the route (the paper's NRTK-surveyed base)."""

    east_m: float = 120.0
    north_m: float = -60.0
    height_above_origin_m: float = 12.0  # on a low roof in the park south of leg A-B
    name: str = "ref"


@dataclass(frozen=True)
class Scenario:
    name: str
    description: str
    start: tuple[int, int, int, int, int, float] = (2024, 6, 24, 8, 10, 0.0)  # GPST calendar
    interval_s: float = 1.0
    nav_file: str = BUNDLED_NAV  # a file in coplane/data/nav, or an absolute path
    road: RoadParams = field(default_factory=RoadParams)
    canyon: CanyonParams = field(default_factory=lambda: CanyonParams(kinds=_urban_buildings()))
    motion: MotionParams = field(default_factory=MotionParams)
    common_mode: CommonModeParams = field(default_factory=CommonModeParams)
    iono: IonoParams = field(default_factory=IonoParams)
    tropo: TropoParams = field(default_factory=TropoParams)
    nlos: NlosParams = field(default_factory=NlosParams)
    vehicle_receiver: ReceiverParams = field(default_factory=ReceiverParams)
    base_receiver: ReceiverParams = field(default_factory=base_receiver_params)
    base: BaseStationParams | None = field(default_factory=BaseStationParams)
    uwb: UwbParams | None = field(default_factory=UwbParams)
    city: CityParams | None = None  # set: many loops of a street grid instead of `road`'s one loop

    def nav_path(self) -> Path:
        p = Path(self.nav_file)
        return p if p.is_absolute() else bundled_nav_path().parent / p


def _open_sky() -> Scenario:
    road = RoadParams(sections=((0.0, "open"),))
    return Scenario(
        name="open-sky",
        description="control: the urban-loop road with no buildings and no underpass",
        road=road,
        canyon=CanyonParams(kinds={}),
    )


def _dense_urban() -> Scenario:
    road = RoadParams(
        sections=(
            (0.0, "open"),
            (200.0, "deep"),
            (700.0, "underpass"),
            (790.0, "deep"),
            (1600.0, "medium"),
            (2260.0, "underpass"),
            (2350.0, "deep"),
            (3446.0, "medium"),
            (3750.0, "open"),
        ),
        grade_changes=(
            GradeChange(330.0, 0.04, 60.0),
            GradeChange(600.0, -0.045, 80.0),
            GradeChange(680.0, 0.0, 20.0),
            GradeChange(830.0, 0.045, 30.0),
            GradeChange(1000.0, 0.0, 50.0),
            GradeChange(1450.0, 0.03, 50.0),
            GradeChange(1700.0, 0.0, 50.0),
            GradeChange(2110.0, -0.045, 40.0),
            GradeChange(2240.0, 0.0, 40.0),
            GradeChange(2370.0, 0.045, 40.0),
            GradeChange(2500.0, 0.0, 40.0),
            GradeChange(2900.0, -0.035, 50.0),
            GradeChange(3200.0, 0.0, 50.0),
        ),
    )
    kinds = {
        "open": BuildingParams(height_m=(3.0, 9.0), setback_m=(28.0, 45.0), fill=0.25),
        "medium": BuildingParams(height_m=(20.0, 45.0), setback_m=(11.0, 16.0), fill=0.9),
        "deep": BuildingParams(height_m=(60.0, 150.0), setback_m=(9.0, 12.0), fill=0.97, gap_m=(2.0, 8.0)),
    }
    veh = ReceiverParams(multipath=MultipathParams(scale=1.3))
    return Scenario(
        name="dense-urban",
        description="hard case: taller towers closer to the road, two underpasses, stronger multipath",
        road=road,
        canyon=CanyonParams(kinds=kinds, underpass=UnderpassParams()),
        vehicle_receiver=veh,
    )


def _city() -> Scenario:
    return Scenario(
        name="city",
        description="load generation: loops of a street grid, platoons of 2-6 that meet and part",
        city=CityParams(),
        base=BaseStationParams(east_m=0.0, north_m=0.0),  # the middle block's centre, 12 m up
    )


SCENARIOS: dict[str, Scenario] = {
    "urban-loop": Scenario(
        name="urban-loop",
        description="default: Zhongguancun circuit with open sky, medium and deep canyons, an underpass",
    ),
    "open-sky": _open_sky(),
    "dense-urban": _dense_urban(),
    "city": _city(),
}
DEFAULT_SCENARIO = "urban-loop"


def get_scenario(name: str) -> Scenario:
    try:
        return SCENARIOS[name]
    except KeyError:
        raise ValueError(f"unknown scenario {name!r}; known: {', '.join(sorted(SCENARIOS))}") from None
