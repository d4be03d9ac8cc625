"""The in-memory model of a fleet recording (../shared/spec/fleet-recording.md).

Readers produce these objects, writers consume them and the simulator builds them. They are plain
frozen dataclasses (no I/O), so the estimator and the services share one vocabulary.
"""

from __future__ import annotations

import math
import statistics
from dataclasses import dataclass, field
from pathlib import Path

from coplane.errors import NotFoundError
from coplane.gtime import GpsTime

SatId = str  # "G05", "C14": system letter + two-digit PRN


@dataclass(frozen=True, slots=True)
class Ephemeris:
    """One broadcast Keplerian ephemeris (GPS LNAV or BeiDou D1/D2), times in GPST.

    BeiDou toc/toe are converted from BDT at parse time, so all time arithmetic is in GPST.
    `iode`/`iodc` hold AODE/AODC for BeiDou. `tgd` is TGD1 (B1I) for BeiDou, TGD for GPS.
    """

    sat: SatId
    toc: GpsTime
    af0: float
    af1: float
    af2: float
    iode: float
    crs: float
    delta_n: float
    m0: float
    cuc: float
    e: float
    cus: float
    sqrt_a: float
    toe: GpsTime
    cic: float
    omega0: float
    cis: float
    i0: float
    crc: float
    omega: float
    omega_dot: float
    idot: float
    week: int  # as broadcast (GPS week for GPS, BDT week for BeiDou)
    sva: float  # URA / accuracy in metres
    health: int
    tgd: float
    tgd2: float = 0.0
    iodc: float = 0.0
    ttr: float = 0.0  # transmission time of message (seconds of week, as broadcast)
    fit_hours: float = 0.0

    @property
    def system(self) -> str:
        return self.sat[0]


@dataclass(frozen=True, slots=True)
class IonoCoefficients:
    """Klobuchar alpha/beta (GPS `GPSA/GPSB`, BeiDou `BDSA/BDSB`)."""

    alpha: tuple[float, float, float, float]
    beta: tuple[float, float, float, float]


@dataclass(slots=True)
class NavData:
    """Merged broadcast navigation data: ephemerides per satellite, sorted by toe."""

    ephemerides: dict[SatId, list[Ephemeris]] = field(default_factory=dict)
    iono: dict[str, IonoCoefficients] = field(default_factory=dict)  # keys "G", "C"

    def add(self, eph: Ephemeris) -> None:
        lst = self.ephemerides.setdefault(eph.sat, [])
        for i, old in enumerate(lst):
            if old.toe == eph.toe and old.iode == eph.iode:
                return  # duplicate record (same ephemeris broadcast again or in two files)
            if eph.toe < old.toe:
                lst.insert(i, eph)
                return
        lst.append(eph)

    def merge(self, other: NavData) -> None:
        for ephs in other.ephemerides.values():
            for e in ephs:
                self.add(e)
        for k, v in other.iono.items():
            self.iono.setdefault(k, v)

    @property
    def satellites(self) -> list[SatId]:
        return sorted(self.ephemerides)

    def reference_time(self) -> GpsTime | None:
        """When this navigation data was broadcast: the median of each satellite's newest toe, to
        place observations that carry only a time of week (RTCM 3 MSM). The median, not the
        newest or the first: a navigation file may hold a stray record of another week (KLT's HKSC
        file has a GPS ephemeris 30 weeks older than the rest), and one such record placed a base
        station's epochs 30 weeks early. None without ephemerides."""
        newest = [ephs[-1].toe for ephs in self.ephemerides.values() if ephs]
        return statistics.median_low(newest) if newest else None


@dataclass(frozen=True, slots=True)
class SatObservation:
    """One satellite's measurements on the selected signal; NaN where not observed."""

    sat: SatId
    pseudorange_m: float = math.nan
    doppler_hz: float = math.nan  # RINEX sign: positive when approaching
    cn0_dbhz: float = math.nan
    carrier_cycles: float = math.nan


@dataclass(frozen=True, slots=True)
class ObsEpoch:
    """One receiver epoch: exact receiver time tag, RINEX epoch flag, satellites."""

    time: GpsTime
    sats: tuple[SatObservation, ...]
    flag: int = 0
    receiver_clock_offset_s: float = 0.0

    def by_sat(self) -> dict[SatId, SatObservation]:
        return {s.sat: s for s in self.sats}


@dataclass(frozen=True, slots=True)
class ObsHeader:
    """What an observation file's header says that matters downstream."""

    version: float
    marker_name: str = ""
    receiver: str = ""
    antenna: str = ""
    approx_position_ecef_m: tuple[float, float, float] | None = None
    antenna_delta_hen_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    obs_types: dict[str, tuple[str, ...]] = field(default_factory=dict)  # system -> codes
    interval_s: float | None = None
    time_system: str = "GPS"


@dataclass(frozen=True, slots=True)
class UwbRange:
    time: GpsTime
    a: str
    b: str
    range_m: float

    @property
    def pair(self) -> tuple[str, str]:
        return (self.a, self.b) if self.a <= self.b else (self.b, self.a)


@dataclass(frozen=True, slots=True)
class TruthPoint:
    time: GpsTime
    ecef_m: tuple[float, float, float]
    # the optional `environment` (or the simulator's `section`) column: open, medium, deep, underpass
    environment: str = ""


@dataclass(frozen=True, slots=True)
class VehicleSpec:
    id: str
    obs: Path
    antenna_height_m: float
    truth: Path | None = None


@dataclass(frozen=True, slots=True)
class BaseSpec:
    obs: Path
    position_ecef_m: tuple[float, float, float]


@dataclass(frozen=True, slots=True)
class UwbSpec:
    file: Path
    sigma_m: float = 0.3
    max_range_m: float = 500.0


@dataclass(frozen=True, slots=True)
class Manifest:
    """fleet.toml, with every path resolved inside the recording directory."""

    root: Path
    name: str
    interval_s: float
    nav_files: tuple[Path, ...]
    vehicles: tuple[VehicleSpec, ...]
    base: BaseSpec | None = None
    uwb: UwbSpec | None = None

    def vehicle(self, vid: str) -> VehicleSpec:
        for v in self.vehicles:
            if v.id == vid:
                return v
        ids = [v.id for v in self.vehicles]
        shown = ", ".join(ids[:10]) + (f", ... ({len(ids)} in all)" if len(ids) > 10 else "")
        raise NotFoundError(f"vehicle {vid!r} is not in recording {self.name!r} (its vehicles: {shown})")
