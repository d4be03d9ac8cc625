"""Response models of every endpoint (they are the OpenAPI schema; no endpoint returns a bare dict).

Floats that can be undefined (an RMSE before the first solved truth epoch) are `None`, never NaN:
JSON has no NaN and clients should not have to special-case it.
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from coplane.messages import EpochTime, PlaneSourceName, PlaneStatusName, PlaneSummary, VehicleCounters

Vec3 = tuple[float, float, float]


class _Out(BaseModel):
    model_config = ConfigDict(extra="forbid")


class Problem(_Out):
    """RFC 7807 problem details (media type application/problem+json)."""

    type: str = Field(default="about:blank", description="URI of the problem type")
    title: str
    status: int = Field(ge=400, le=599)
    detail: str | None = None
    instance: str | None = Field(default=None, description="The request path")
    errors: list[dict[str, Any]] | None = Field(default=None, description="Validation errors (422 only)")


class Origin(_Out):
    """The local ENU frame's origin: the first position the API saw (reset when a replay restarts)."""

    ecef_m: Vec3
    lat_deg: float
    lon_deg: float
    height_m: float


class VehicleSummary(_Out):
    vehicle_id: str
    online: bool = Field(description="The vehicle's agent liveliness token is present on the bus")
    server_online: bool | None = Field(
        default=None, description="The fusion server counts the vehicle as live (last diagnostics)"
    )
    method: str | None = None
    seq: int | None = Field(default=None, description="Sequence number of the solution it came from")
    epoch: EpochTime | None = Field(default=None, description="Nominal GPS epoch of the latest state")
    gps_s: float | None = Field(default=None, description="Same epoch as GPS seconds (week * 604800 + tow)")
    position_ecef_m: Vec3 | None = None
    lat_deg: float | None = None
    lon_deg: float | None = None
    height_m: float | None = None
    enu_m: Vec3 | None = Field(default=None, description="Position in the fleet's local ENU frame")
    sigma_h_m: float | None = Field(default=None, description="sqrt(var E + var N) from the covariance")
    sigma_v_m: float | None = None
    has_gnss_fix: bool | None = None
    spp_ok: bool | None = None
    plane_status: PlaneStatusName | None = None
    plane_used: bool | None = None
    plane_source: PlaneSourceName | None = Field(
        default=None, description="Where the vehicle's plane came from: fleet, self or map (null: no plane)"
    )
    n_satellites: int | None = None
    n_pseudoranges: int | None = None
    excluded_satellites: list[str] | None = Field(
        default=None,
        description="The satellites the estimator left out of this epoch (FDE, gate, dead reckoning)",
    )
    raim_excluded: list[str] | None = Field(
        default=None,
        description="The satellites the vehicle agent's RAIM excluded before the estimator saw them",
    )
    hdop: float | None = Field(default=None, description="HDOP of the satellites the agent's fix used")
    vdop: float | None = Field(default=None, description="VDOP of the satellites the agent's fix used")
    n_ranges: int | None = None
    dgnss_age_s: float | None = Field(
        default=None, description="Age of the base corrections this state's SPP used (None: no DGNSS)"
    )
    error_h_m: float | None = Field(default=None, description="Horizontal error vs truth at this epoch")
    error_v_m: float | None = Field(default=None, description="Signed vertical error vs truth")
    age_s: float | None = Field(default=None, description="Wall seconds since this state arrived")


class VehicleDetail(VehicleSummary):
    covariance_m2: list[float] | None = Field(default=None, description="3x3 ECEF row-major, m^2")
    covariance_enu_m2: list[float] | None = Field(default=None, description="3x3 ENU row-major, m^2")
    clocks_s: dict[str, float] = Field(default_factory=dict)
    antenna_height_m: float | None = None
    plane: PlaneSummary | None = None
    counters: VehicleCounters | None = Field(
        default=None, description="The fusion server's message accounting for this vehicle"
    )
    track_points: int = Field(default=0, ge=0, description="Points held in the bounded track history")


class VehicleList(_Out):
    fleet: str
    method: str | None = None
    epoch: EpochTime | None = Field(default=None, description="Latest solved epoch")
    origin: Origin | None = None
    vehicles: list[VehicleSummary]


class TrackPoint(_Out):
    week: int
    tow: float
    gps_s: float
    position_ecef_m: Vec3
    lat_deg: float
    lon_deg: float
    height_m: float
    enu_m: Vec3
    covariance_m2: list[float] | None = None
    plane_status: PlaneStatusName | None = None
    error_h_m: float | None = None
    error_v_m: float | None = Field(default=None, description="Signed vertical error vs truth")
    n_satellites: int = Field(default=0, description="Pseudoranges the vehicle agent used")
    n_pseudoranges: int = Field(default=0, description="Of those, the ones the estimator kept")
    excluded_satellites: list[str] = Field(
        default_factory=list, description="The ones the estimator left out"
    )
    raim_excluded: list[str] = Field(default_factory=list, description="The ones the agent's RAIM excluded")
    vdop: float | None = Field(default=None, description="VDOP of the satellites the agent's fix used")
    has_gnss_fix: bool = Field(
        default=True,
        description="The epoch's own pseudoranges fix it (false: motion, ranges or the plane carry it)",
    )
    dgnss_age_s: float | None = Field(
        default=None, description="Age of the DGNSS corrections the agent's fix used (null: standalone)"
    )
    n_ranges: int = Field(default=0, description="Ranges to other vehicles the estimator used")
    plane_used: bool = Field(default=False, description="A road plane constrained the estimate")
    plane_source: PlaneSourceName | None = Field(
        default=None,
        description="Where the vehicle's plane came from: fleet (fitted from the fleet's history), "
        "self (from its own) or map (the road-surface map); null: no plane",
    )
    hdop: float | None = Field(default=None, description="HDOP of the satellites the agent's fix used")


class Track(_Out):
    vehicle_id: str
    fleet: str
    since: float | None = Field(default=None, description="Only points with gps_s > since")
    capacity: int = Field(description="history_per_vehicle: older points were dropped")
    points: list[TrackPoint]


class GeoJsonLineString(_Out):
    type: Literal["LineString"] = "LineString"
    coordinates: list[list[float]] = Field(description="[lon, lat, height] per point (RFC 7946)")


class GeoJsonPoint(_Out):
    type: Literal["Point"] = "Point"
    coordinates: list[float]


class GeoJsonFeature(_Out):
    type: Literal["Feature"] = "Feature"
    geometry: GeoJsonLineString | GeoJsonPoint
    properties: dict[str, Any]


class GeoJsonFeatureCollection(_Out):
    type: Literal["FeatureCollection"] = "FeatureCollection"
    features: list[GeoJsonFeature]


class PlaneCounts(_Out):
    available: int = 0
    available_after_fe: int = 0
    unavailable: int = 0
    none: int = Field(default=0, description="Epochs where the vehicle sent no plane")


class PlaneEntry(_Out):
    vehicle_id: str
    epoch: EpochTime | None = None
    status: PlaneStatusName | None = None
    reason: str | None = None
    plane_used: bool | None = Field(default=None, description="The estimator used the plane factor")
    residual_max_m: float | None = None
    residual_rms_m: float | None = None
    sigma_m: float | None = None
    n_points_initial: int = 0
    n_points_used: int = 0
    counts: PlaneCounts
    availability_ratio: float | None = Field(
        default=None, description="(available + after FE) / epochs with a plane report"
    )


class PlaneList(_Out):
    fleet: str
    now: PlaneCounts = Field(description="Vehicles per status at their latest epoch")
    availability_ratio: float | None = Field(default=None, description="Fleet-wide, all epochs seen")
    vehicles: list[PlaneEntry]


class AccuracyEntry(_Out):
    """Running accuracy of one vehicle under one method (errors in ENU at the truth point)."""

    vehicle_id: str
    method: str
    n_truth: int = Field(description="Truth epochs between the first and the latest epoch seen")
    n_solved: int = Field(description="Of those, epochs with a solution")
    availability: float
    h_rmse_m: float | None = None
    v_rmse_m: float | None = None
    cep95_m: float | None = Field(default=None, description="95th percentile horizontal error")
    cep95_samples: int = Field(description="Errors behind cep95_m (bounded by accuracy_window)")
    h_max_m: float | None = None
    v_max_m: float | None = None
    h_mean_m: float | None = None
    v_bias_m: float | None = None
    last_error_h_m: float | None = None


class AccuracyReport(_Out):
    fleet: str
    truth_vehicles: list[str] = Field(description="Vehicles with truth in the recording")
    entries: list[AccuracyEntry]


class Health(_Out):
    status: Literal["ok"] = "ok"
    version: str
    uptime_s: float


class Readiness(_Out):
    ready: bool
    bus_connected: bool
    fusion_alive: bool = Field(description="A fusion server liveliness token (alive/fusion/*) is present")
    solutions_received: int
    last_solution_age_s: float | None = None
    live_agents: int
    reasons: list[str] = Field(description="Why not ready (empty when ready)")


class ServerRegions(_Out):
    server: str
    alive: bool = Field(description="Its liveliness token (alive/fusion/<server>) is present")
    shards: list[int] = Field(description="The shards it owns (rendezvous hashing over the live servers)")
    regions: dict[str, list[str]] = Field(description="Region -> the vehicles it last heard there")
    epochs_solved: int


class RegionOwnership(_Out):
    servers: list[ServerRegions]
    live_servers: list[str]
    overlapping_shards: list[int] = Field(
        description="Shards two live servers claim (they see different live sets: a change in progress)"
    )


class StreamVehicle(_Out):
    vehicle_id: str
    enu_m: Vec3
    lat_deg: float
    lon_deg: float
    sigma_h_m: float | None = None
    plane_status: PlaneStatusName | None = None
    plane_used: bool
    has_gnss_fix: bool
    error_h_m: float | None = None
    online: bool


class StreamEvent(_Out):
    """The `data` of each `solution` event on /stream: one fleet epoch, compact."""

    fleet: str
    method: str
    seq: int
    epoch: EpochTime
    gps_s: float
    solve_time_s: float
    latency_s: float | None = Field(default=None, description="Now - oldest node message publish time")
    origin: Origin
    vehicles: list[StreamVehicle]
