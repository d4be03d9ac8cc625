"""Wire models for everything that crosses a process boundary (versioned pydantic models).

The per-vehicle step produces a `NodeMessage`, the fusion step consumes node messages and produces
a `SolutionMessage`; the in-process evaluator passes the very same objects, so a lockstep replay
over the bus and `coplane eval` compute on identical inputs (JSON floats round-trip exactly).
Every field is validated at the boundary: non-finite numbers, absurd magnitudes, malformed ids and
oversized lists are rejected with a reason. The bounds are `coplane.estimation.limits`, the
same the estimators apply, so what passes here is never rejected there for another limit.

It stays one file: it is one format, the bus's versioned wire schema, whose models nest in one
another and share their bounds.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from coplane.estimation.limits import (
    MAX_ANTENNA_HEIGHT_M,
    MAX_DRIFT_MPS,
    MAX_NORMAL_ERROR,
    MAX_PLANE_SIGMA_M,
    MAX_RANGE_M,
    MAX_RANGE_SIGMA_M,
    MAX_SAT_CLOCK_S,
    MAX_SIGMA_M,
    MAX_SPEED_MPS,
    PSEUDORANGE_M,
    RECEIVER_RADIUS_M,
    SAT_ID_PATTERN,
    SAT_RADIUS_M,
)
from coplane.ids import VEHICLE_ID_PATTERN
from coplane.typing import Pace

NODE_SCHEMA = "coplane.node/2"
SOLUTION_SCHEMA = "coplane.solution/1"
DIAGNOSTICS_SCHEMA = "coplane.diagnostics/1"

VehicleId = Annotated[str, Field(pattern=VEHICLE_ID_PATTERN)]
SatId = Annotated[str, Field(pattern=SAT_ID_PATTERN)]
Ecef = Annotated[tuple[float, float, float], Field(description="WGS-84 ECEF metres")]
Cov3 = Annotated[list[float], Field(min_length=9, max_length=9, description="3x3 row-major, m^2")]
Metres = Annotated[float, Field(ge=-1e8, le=1e8)]
# A fusion server run: consumers reset their state only when it changes (a resumed server keeps it)
Generation = Annotated[str, Field(pattern=r"^[0-9a-f]{8,32}$")]

MAX_SATELLITES = 64
MAX_RANGES = 256
MAX_MAP_COUNTS = 64  # kinds of road-map evidence counts in a diagnostics message


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class EpochTime(_Model):
    week: int = Field(ge=0, le=10000)
    tow: float = Field(ge=0.0, lt=604800.0)


def _check_ecef(v: tuple[float, float, float], what: str, bounds: tuple[float, float]) -> None:
    lo, hi = bounds
    r = (v[0] ** 2 + v[1] ** 2 + v[2] ** 2) ** 0.5
    if not lo <= r <= hi:
        raise ValueError(f"{what} is {r:.0f} m from the Earth's centre (expected {lo:.0f}..{hi:.0f})")


# One satellite's values and their bounds, shared by the row (`SatelliteReport`) and the wire's
# columns (`SatelliteColumns`), so that both check every value alike
PseudorangeM = Annotated[float, Field(ge=PSEUDORANGE_M[0], le=PSEUDORANGE_M[1])]
DopplerHz = Annotated[float, Field(ge=-1e5, le=1e5)]
Cn0DbHz = Annotated[float, Field(ge=0.0, le=70.0)]
ElevationDeg = Annotated[float, Field(ge=-90.0, le=90.0)]
AzimuthDeg = Annotated[float, Field(ge=0.0, le=360.0)]
SatClockS = Annotated[float, Field(ge=-MAX_SAT_CLOCK_S, le=MAX_SAT_CLOCK_S)]
TgdM = Annotated[float, Field(ge=-100.0, le=100.0)]
IonoM = Annotated[float, Field(ge=-100.0, le=200.0)]
TropoM = Annotated[float, Field(ge=0.0, le=100.0)]
DgnssM = Annotated[float, Field(ge=-500.0, le=500.0)]
SigmaM = Annotated[float, Field(gt=0.0, le=MAX_SIGMA_M)]
Reason = Annotated[str, Field(max_length=200)]


class SatelliteReport(_Model):
    """One tracked satellite: raw measurements, the states and corrections used, the factor input.

    A row of `SatelliteColumns` (`SatelliteColumns.rows()`): what a reader of one satellite, a
    test or a log line wants; the wire carries the columns."""

    sat: SatId
    pseudorange_m: PseudorangeM
    doppler_hz: DopplerHz | None = None
    cn0_dbhz: Cn0DbHz | None = None
    elevation_deg: ElevationDeg
    azimuth_deg: AzimuthDeg
    sat_pos_ecef_m: Ecef  # in the ECEF frame at reception (Sagnac applied)
    sat_clock_s: SatClockS
    tgd_m: TgdM
    iono_m: IonoM
    tropo_m: TropoM
    dgnss_m: DgnssM | None = None
    rho_m: PseudorangeM  # corrected, fed to the factor
    sigma_m: SigmaM
    used: bool = True  # False: excluded by the vehicle's RAIM
    excluded_reason: Reason | None = None

    @model_validator(mode="after")
    def _sat_far_away(self) -> SatelliteReport:
        _check_ecef(self.sat_pos_ecef_m, f"satellite {self.sat} position", SAT_RADIUS_M)
        return self


def _column() -> Any:
    """A column of `SatelliteColumns`: one value per satellite of the message."""
    return Field(default_factory=list, max_length=MAX_SATELLITES)


class SatelliteColumns(_Model):
    """A node message's satellites, one list per `SatelliteReport` field, index i = satellite i.

    Why columns, not an object per satellite: a fusion server decodes every vehicle's message
    every epoch, and pydantic-core validates a list of numbers under one bound without making a
    model per satellite; the server's self-check and the estimator then take arrays straight
    from the lists. Measured (docs/performance-scale.md, "Node messages as columns"): decoding
    costs 40 % less, and the message is 42 % smaller, as the field names are written once.
    Every value keeps its row's bound; the lists must have one value per satellite, the
    satellites must be unique and each orbit radius plausible."""

    sat: list[SatId] = _column()
    pseudorange_m: list[PseudorangeM] = _column()
    doppler_hz: list[DopplerHz | None] = _column()
    cn0_dbhz: list[Cn0DbHz | None] = _column()
    elevation_deg: list[ElevationDeg] = _column()
    azimuth_deg: list[AzimuthDeg] = _column()
    sat_pos_ecef_m: list[Ecef] = _column()
    sat_clock_s: list[SatClockS] = _column()
    tgd_m: list[TgdM] = _column()
    iono_m: list[IonoM] = _column()
    tropo_m: list[TropoM] = _column()
    dgnss_m: list[DgnssM | None] = _column()
    rho_m: list[PseudorangeM] = _column()
    sigma_m: list[SigmaM] = _column()
    used: list[bool] = _column()
    excluded_reason: list[Reason | None] = _column()

    @model_validator(mode="after")
    def _one_value_per_satellite(self) -> SatelliteColumns:
        n = len(self.sat)
        for name in type(self).model_fields:
            got = len(getattr(self, name))
            if got != n:
                raise ValueError(f"satellite column {name} has {got} values, column sat has {n}")
        if len(set(self.sat)) != n:
            raise ValueError("duplicate satellite in one node message")
        for sat, pos in zip(self.sat, self.sat_pos_ecef_m, strict=True):
            _check_ecef(pos, f"satellite {sat} position", SAT_RADIUS_M)
        return self

    def __len__(self) -> int:
        return len(self.sat)

    @staticmethod
    def data_of(rows: Sequence[SatelliteReport | Mapping[str, Any]]) -> dict[str, list[Any]]:
        """The columns of satellites given one by one (reports, or dicts of their fields), as
        plain lists and not yet validated; a field a dict leaves out takes the row's default."""
        dicts = [r.model_dump() if isinstance(r, SatelliteReport) else r for r in rows]
        fields = SatelliteReport.model_fields
        return {n: [d[n] if n in d else fields[n].get_default() for d in dicts] for n in fields}

    @classmethod
    def from_rows(cls, rows: Sequence[SatelliteReport | Mapping[str, Any]]) -> SatelliteColumns:
        """The validated columns of satellites given one by one (`data_of`)."""
        return cls.model_validate(cls.data_of(rows))

    def rows(self) -> list[SatelliteReport]:
        """One `SatelliteReport` per satellite (validated again: for readers of one satellite, not
        for a per-epoch path)."""
        names = list(type(self).model_fields)
        return [
            SatelliteReport.model_validate(dict(zip(names, vals, strict=True)))
            for vals in zip(*(getattr(self, n) for n in names), strict=True)
        ]


class SppReport(_Model):
    ok: bool
    reason: str | None = Field(default=None, max_length=300)
    position_ecef_m: Ecef | None = None
    covariance_m2: Cov3 | None = None
    clocks_m: dict[str, float] = Field(default_factory=dict, max_length=4)
    n_used: int = Field(default=0, ge=0, le=MAX_SATELLITES)
    excluded: list[SatId] = Field(default_factory=list, max_length=MAX_SATELLITES)
    gdop: float | None = Field(default=None, ge=0.0, le=1e6)
    pdop: float | None = Field(default=None, ge=0.0, le=1e6)
    hdop: float | None = Field(default=None, ge=0.0, le=1e6)
    vdop: float | None = Field(default=None, ge=0.0, le=1e6)
    dgnss_age_s: float | None = Field(
        default=None,
        ge=-60.0,
        le=3600.0,
        description="receiver time minus the base epoch used (None: no DGNSS)",
    )

    @model_validator(mode="after")
    def _consistent(self) -> SppReport:
        if self.ok and self.position_ecef_m is None:
            raise ValueError("an SPP fix needs position_ecef_m")
        if self.position_ecef_m is not None:
            _check_ecef(self.position_ecef_m, "SPP position", RECEIVER_RADIUS_M)
        return self


class VelocityReport(_Model):
    velocity_ecef_mps: tuple[float, float, float]
    sigma_mps: float = Field(gt=0.0, le=100.0)
    clock_drift_mps: float = Field(ge=-MAX_DRIFT_MPS, le=MAX_DRIFT_MPS)
    n_used: int = Field(ge=0, le=MAX_SATELLITES)
    # solved from 3-4 satellites with a level-road and a carried-drift pseudo-measurement
    # (coplane.gnss.doppler, few-satellite mode): users see where a velocity came from
    few_satellites: bool = False
    # the receiver stands (coplane.gnss.standstill): the fusion may hold it still
    standstill: bool = False

    @model_validator(mode="after")
    def _plausible(self) -> VelocityReport:
        speed = sum(v * v for v in self.velocity_ecef_mps) ** 0.5
        if speed > MAX_SPEED_MPS:
            raise ValueError(f"velocity above {MAX_SPEED_MPS:.0f} m/s is not a road vehicle")
        if self.standstill and speed > 0.0:
            raise ValueError(f"a standstill velocity must be zero, got {speed:.3g} m/s")
        return self


PlaneStatusName = Literal["available", "available-after-fe", "unavailable"]
# where a vehicle's plane came from: fitted from the fleet's or its own solved history (paper
# Sec. III), or taken from the road-surface map (docs/roadmap.md)
PlaneSourceName = Literal["fleet", "self", "map"]


class PlaneReport(_Model):
    """The road plane the vehicle fitted (paper Sec. III), translated to its antenna height."""

    status: PlaneStatusName
    reason: str | None = Field(default=None, max_length=300)
    normal: tuple[float, float, float] | None = None  # unit, upward, ECEF
    d_antenna_m: float | None = None
    d_road_m: float | None = None
    sigma_m: float | None = Field(default=None, gt=0.0, le=MAX_PLANE_SIGMA_M)  # what the factor uses
    offset_sigma_m: float | None = Field(default=None, ge=0.0, le=100.0)  # from the points' own sigma
    tilt_sigma_rad: float | None = Field(default=None, ge=0.0, le=3.15)  # normal, least-determined axis
    residual_max_m: float | None = Field(default=None, ge=0.0)
    residual_rms_m: float | None = Field(default=None, ge=0.0)
    n_points_initial: int = Field(default=0, ge=0, le=100000)
    n_points_used: int = Field(default=0, ge=0, le=100000)
    centroid_ecef_m: Ecef | None = None
    source: PlaneSourceName | None = None  # None: a sender from before the map existed
    map_tile: str | None = Field(default=None, max_length=32)  # the map tile, when source is "map"
    map_passes: int | None = Field(default=None, ge=0)  # passes behind that tile's plane

    @model_validator(mode="after")
    def _usable(self) -> PlaneReport:
        if self.status != "unavailable":
            if self.normal is None or self.d_antenna_m is None or self.sigma_m is None:
                raise ValueError("an available plane needs normal, d_antenna_m and sigma_m")
            n = sum(c * c for c in self.normal) ** 0.5
            if abs(n - 1.0) > MAX_NORMAL_ERROR:
                raise ValueError(f"plane normal is not unit length ({n:.6f})")
        return self


class RangeReport(_Model):
    to: VehicleId
    range_m: float = Field(gt=0.0, le=MAX_RANGE_M)
    sigma_m: float = Field(gt=0.0, le=MAX_RANGE_SIGMA_M)


class NodeMessage(_Model):
    """What one vehicle sends the fusion server for one epoch (paper Fig. 2, "node message")."""

    # /2: the satellites as columns (`SatelliteColumns`); /1 had an object per satellite
    schema_: Literal["coplane.node/2"] = Field(default="coplane.node/2", alias="schema")
    fleet: VehicleId
    vehicle_id: VehicleId
    seq: int = Field(ge=0)
    epoch: EpochTime  # nominal epoch (multiple of the interval)
    rx_time: EpochTime  # the receiver's exact tag
    antenna_height_m: float = Field(ge=0.0, le=MAX_ANTENNA_HEIGHT_M)
    spp: SppReport
    velocity: VelocityReport | None = None
    satellites: SatelliteColumns = Field(default_factory=SatelliteColumns)
    plane: PlaneReport | None = None
    ranges: list[RangeReport] = Field(default_factory=list, max_length=MAX_RANGES)
    sent_unix_s: float | None = Field(
        default=None, ge=0.0, description="wall clock at publish (latency only)"
    )

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False, populate_by_name=True)

    @model_validator(mode="after")
    def _unique(self) -> NodeMessage:
        peers = [r.to for r in self.ranges]
        if len(set(peers)) != len(peers) or self.vehicle_id in peers:
            raise ValueError("ranges must name each peer once and not the vehicle itself")
        return self


class PlaneSummary(_Model):
    """What the API and plots show about the plane a vehicle sent (status and why)."""

    status: PlaneStatusName
    reason: str | None = Field(default=None, max_length=300)
    residual_max_m: float | None = None
    residual_rms_m: float | None = None
    sigma_m: float | None = None
    offset_sigma_m: float | None = None
    n_points_initial: int = 0
    n_points_used: int = 0
    source: PlaneSourceName | None = None
    map_tile: str | None = Field(default=None, max_length=32)


FixKind = Literal["dgnss", "single", "dead-reckoned"]


def fix_kind(has_gnss_fix: bool, dgnss_age_s: float | None) -> FixKind:
    """What kind of fix a fused solution is: "dgnss" or "single" when the epoch's own pseudoranges
    fix it, with or without the base's corrections at that epoch; "dead-reckoned" when they do not
    and motion, ranges or the plane carry it. The one rule behind RTKLIB's Q in the .pos files
    (`evaluate.solution_files.pos_quality`) and NMEA's GGA quality and RMC mode (`live.nmea_out`)."""
    if not has_gnss_fix:
        return "dead-reckoned"
    return "single" if dgnss_age_s is None else "dgnss"


def plane_source(plane: PlaneReport | PlaneSummary | None) -> PlaneSourceName | None:
    """Where the plane a vehicle had came from, or None when it had none: an unavailable plane's
    `source` only says where the agent looked. The rule of the solution CSV's `plane_source` column
    and of the API's track points, so that both say the same of an epoch."""
    if plane is None or plane.status == "unavailable":
        return None
    return plane.source


class VehicleState(_Model):
    vehicle_id: VehicleId
    position_ecef_m: Ecef
    covariance_m2: Cov3 | None = None
    clocks_s: dict[str, float] = Field(default_factory=dict, max_length=4)
    antenna_height_m: float = Field(ge=0.0, le=MAX_ANTENNA_HEIGHT_M)
    n_pseudoranges: int = Field(ge=0)
    n_ranges: int = Field(ge=0)
    plane_used: bool
    plane_status: PlaneStatusName | None = None
    plane: PlaneSummary | None = None
    has_gnss_fix: bool
    n_satellites: int = Field(default=0, ge=0)
    spp_ok: bool = False
    dgnss_age_s: float | None = None  # age of the base corrections this epoch's SPP used
    # the node's pseudoranges the estimator left out (FDE, gate, cooperative check, dead
    # reckoning): n_satellites - n_pseudoranges of them, by name
    excluded_satellites: list[SatId] = Field(default_factory=list, max_length=MAX_SATELLITES)
    # the agent's side of the same question: what its SPP's RAIM excluded, and the geometry of the
    # satellites it used (a VDOP of 8 says why a height is poor before any error is known)
    raim_excluded: list[SatId] = Field(default_factory=list, max_length=MAX_SATELLITES)
    hdop: float | None = Field(default=None, ge=0.0, le=1e6)
    vdop: float | None = Field(default=None, ge=0.0, le=1e6)


class SolutionMessage(_Model):
    """The fleet solution of one epoch, sent back to the vehicles and to the API."""

    schema_: Literal["coplane.solution/1"] = Field(default="coplane.solution/1", alias="schema")
    fleet: VehicleId
    method: str = Field(max_length=64)
    seq: int = Field(ge=0)
    epoch: EpochTime
    vehicles: list[VehicleState] = Field(max_length=4096)
    solve_time_s: float = Field(ge=0.0)
    factor_counts: dict[str, int] = Field(default_factory=dict)
    missing: list[VehicleId] = Field(default_factory=list)  # live vehicles that did not report
    oldest_node_sent_unix_s: float | None = None  # for end-to-end latency (node publish -> solution)
    generation: Generation | None = None  # the server run that solved it (same after a resume)
    # regions (docs/scale.md): which of several servers solved it, and the vehicles whose node
    # messages of this epoch it answers (a lockstep agent waits for the solution that names it)
    server: VehicleId | None = None
    answered: list[VehicleId] = Field(default_factory=list, max_length=4096)

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False, populate_by_name=True)

    def answers(self, vehicle_id: str) -> bool:
        """Whether this solution is the answer to `vehicle_id`'s node message of its epoch: the
        single server's answers every vehicle; with regions only the owning server's does."""
        return self.server is None or vehicle_id in self.answered


class VehicleCounters(_Model):
    """Per-vehicle message accounting at the fusion server: received = used + rejected + late +
    duplicate + elsewhere."""

    received: int = 0
    used: int = 0
    rejected: int = 0
    late: int = 0
    duplicate: int = 0
    out_of_order: int = 0
    missing: int = 0  # epochs solved while this live vehicle had not reported
    elsewhere: int = 0  # regions: messages heard across a boundary, solved by another server
    online: bool = False


class DiagnosticsMessage(_Model):
    schema_: Literal["coplane.diagnostics/1"] = Field(default="coplane.diagnostics/1", alias="schema")
    fleet: VehicleId
    method: str = Field(max_length=64)
    pace: Pace
    epochs_solved: int = Field(ge=0)
    last_epoch: EpochTime | None = None
    last_solve_time_s: float | None = None
    vehicles: dict[str, VehicleCounters] = Field(default_factory=dict)
    rejected_by_reason: dict[str, int] = Field(default_factory=dict)  # includes unattributable payloads
    live_vehicles: list[str] = Field(default_factory=list)
    node_payloads: int = Field(default=0, ge=0)  # every payload seen on node keys
    pending_epochs: int = Field(default=0, ge=0)  # epochs waiting to be solved
    pending_limit: int = Field(default=0, ge=0)  # the bound on pending_epochs (0: not reported)
    # processes solving the factor graph's clusters (`--cluster_workers`), and how many of them died
    cluster_workers: int = Field(default=1, ge=1, le=64)
    cluster_workers_lost: int = Field(default=0, ge=0, le=64)
    generation: Generation | None = None
    # regions (docs/scale.md): this server, the live servers it sees, the shards it owns and the
    # regions its vehicles were last in
    server: VehicleId | None = None
    servers: list[VehicleId] = Field(default_factory=list, max_length=256)
    shards: list[Annotated[int, Field(ge=0, le=4096)]] = Field(default_factory=list, max_length=4096)
    regions: dict[str, list[VehicleId]] = Field(default_factory=dict, max_length=4096)
    # how its region role decided (vehicles solved for another server's answer, hand-over seeds,
    # copies skipped, ...; `RegionRole.counts`)
    region_counts: dict[Annotated[str, Field(max_length=64)], Annotated[int, Field(ge=0)]] = Field(
        default_factory=dict, max_length=64
    )

    # the road map's common residual (docs/roadmap.md): the median height of recent passes against
    # the map over every usable tile (+: the fleet's heights are above the map), and the passes it
    # rests on; None while the server has no map or too few recent passes
    map_common_offset_m: float | None = Field(default=None, ge=-1000.0, le=1000.0)
    map_common_passes: int = Field(default=0, ge=0)
    # what became of the fleet's evidence for the road map (samples, passes_added, skipped:<reason>,
    # ...; `LiveRoadMap.evidence_counts`): why a map does not learn (e.g. a standalone fleet)
    map_counts: dict[Annotated[str, Field(max_length=64)], Annotated[int, Field(ge=0)]] = Field(
        default_factory=dict, max_length=MAX_MAP_COUNTS
    )

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False, populate_by_name=True)

    @model_validator(mode="after")
    def _lost_workers(self) -> DiagnosticsMessage:
        if self.cluster_workers_lost > self.cluster_workers:  # the API's gauge subtracts them
            raise ValueError(f"cluster_workers_lost > cluster_workers ({self.cluster_workers})")
        if (self.map_common_offset_m is None) != (self.map_common_passes == 0):
            raise ValueError("map_common_offset_m needs map_common_passes >= 1, and passes need an offset")
        return self


class MapTileState(_Model):
    """One road-map tile as the fusion server shares it (docs/roadmap.md): the plane's evidence in
    information form, enough for `RoadMap.plane_at`; the change detector's state stays with the
    writer."""

    tile: str = Field(pattern=r"^r-?\d{1,9}c-?\d{1,9}$")
    h0_m: float = Field(ge=-1000.0, le=10000.0)
    info: list[float] = Field(min_length=6, max_length=6, description="upper triangle, row-major")
    eta: list[float] = Field(min_length=3, max_length=3)
    n_passes: int = Field(ge=0)
    n_points: int = Field(ge=0)
    outlier_passes: int = Field(default=0, ge=0)
    changes: int = Field(default=0, ge=0)
    version: int = Field(ge=0)
    updated_s: float = 0.0


class MapTilesMessage(_Model):
    """A batch of road-map tiles from the fusion server: the whole map in `parts` messages of one
    `snapshot` (at start and then periodically), or the tiles one commit changed (`parts` 0).
    `server`: the writer's id when several servers share the fleet by region ('' for one server),
    so a snapshot's parts are counted per server and a server skips its own batches.

    An answer to an agent's area query (docs/roadmap.md, "Tiles on the bus") is `parts` messages
    too, with the answering server's `run` (one per server process) and the `revision` of its map
    the answer is complete up to, which the agent names in its next query ('' and 0 otherwise)."""

    schema_: Literal["coplane.map_tiles/1"] = Field(default="coplane.map_tiles/1", alias="schema")
    fleet: VehicleId
    server: str = Field(default="", pattern=r"^[A-Za-z0-9_-]{0,32}$")
    tile_size_m: float = Field(gt=0.0, le=1000.0)
    snapshot: int = Field(ge=0)
    part: int = Field(ge=0)
    parts: int = Field(ge=0)
    tiles: list[MapTileState] = Field(max_length=1000)
    run: str = Field(default="", pattern=r"^[0-9a-f]{0,32}$")
    revision: int = Field(default=0, ge=0)

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False, populate_by_name=True)


def merge_diagnostics(diags: list[DiagnosticsMessage]) -> DiagnosticsMessage:
    """Several fusion servers' diagnostics (regions, docs/scale.md) as one fleet-wide message:
    per-vehicle counters and rejections added (each server's add up, so the sums do too), epochs
    as the furthest server's, live vehicles, shards and regions united, region counts added."""
    first = diags[0]
    vehicles: dict[str, VehicleCounters] = {}
    for d in diags:
        for vid, c in d.vehicles.items():
            cur = vehicles.get(vid)
            if cur is None:
                vehicles[vid] = c
                continue
            counts = {
                k: getattr(cur, k) + getattr(c, k)
                for k, f in VehicleCounters.model_fields.items()
                if f.annotation is int
            }
            vehicles[vid] = VehicleCounters(**counts, online=cur.online or c.online)
    rejected: dict[str, int] = {}
    region_counts: dict[str, int] = {}
    regions: dict[str, list[str]] = {}
    for d in diags:
        for k, n in d.rejected_by_reason.items():
            rejected[k] = rejected.get(k, 0) + n
        for k, n in d.region_counts.items():
            region_counts[k] = region_counts.get(k, 0) + n
        for r, vs in d.regions.items():
            regions[r] = sorted(set(regions.get(r, [])) | set(vs))
    epochs = [d.last_epoch for d in diags if d.last_epoch is not None]
    return first.model_copy(
        update={
            "epochs_solved": max(d.epochs_solved for d in diags),
            "last_epoch": max(epochs, key=lambda e: (e.week, e.tow)) if epochs else None,
            "last_solve_time_s": max((d.last_solve_time_s or 0.0) for d in diags),
            "vehicles": dict(sorted(vehicles.items())),
            "rejected_by_reason": rejected,
            "live_vehicles": sorted({v for d in diags for v in d.live_vehicles}),
            "node_payloads": sum(d.node_payloads for d in diags),
            "pending_epochs": sum(d.pending_epochs for d in diags),
            "pending_limit": sum(d.pending_limit for d in diags),
            "generation": None,
            "server": None,
            "servers": sorted({s for d in diags for s in (d.servers or ([d.server] if d.server else []))}),
            "shards": sorted({s for d in diags for s in d.shards}),
            "regions": dict(sorted(regions.items())),
            "region_counts": dict(sorted(region_counts.items())[:64]),
        }
    )
