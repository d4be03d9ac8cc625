"""Vehicle agent configuration (env COPLANE_AGENT_*, TOML table [agent], or --flags)."""

from __future__ import annotations

from pathlib import Path

from pydantic import Field
from pydantic_settings import SettingsConfigDict

from coplane.runtime import LogLevel, RegionOptions, ServiceSettings
from coplane.typing import Pace


class AgentSettings(ServiceSettings, RegionOptions):
    model_config = SettingsConfigDict(env_prefix="COPLANE_AGENT_", extra="ignore")
    toml_table: str = "agent"

    recording: Path = Field(
        description="Fleet recording directory (fleet.toml): the fleet's vehicles, base position and "
        "UWB settings; with --gnss its observation files are not read (docs/live.md)"
    )
    vehicle_id: str = Field(description="Which vehicle of the recording this agent replays")
    gnss: str | None = Field(
        default=None,
        description="Live receiver stream instead of the recording's file, e.g. ubx+tcp://HOST:PORT, "
        "rtcm3+serial:///dev/ttyACM0?baud=115200, ubx+file:///path/log.ubx (docs/live.md)",
    )
    base: str | None = Field(
        default=None,
        description="Live base corrections (RTCM 3), e.g. ntrip://user:pass@HOST:2101/MOUNT; "
        "with --gnss, default: none",
    )
    uwb: str | None = Field(default=None, description="Live UWB ranges, e.g. udp://:5600 (docs/live.md)")
    max_correction_age_s: float = Field(
        default=30.0, gt=0.0, description="Live: base corrections older than this are dropped"
    )
    align_wait_s: float = Field(
        default=0.3, ge=0.0, description="Live realtime: how long an epoch waits for the base's and UWB's"
    )
    method: str = "pc"
    fleet: str | None = Field(default=None, description="Bus fleet id; default: from the recording name")
    connect: list[str] = Field(default_factory=lambda: ["tcp/127.0.0.1:7447"])
    pace: Pace = "lockstep"
    speed: float = Field(default=1.0, gt=0.0, description="Realtime replay speed factor")
    start_unix_s: float | None = Field(
        default=None,
        description="Realtime: wall-clock time of the recording's first epoch, shared by the fleet, so a "
        "restarted agent rejoins at the current epoch; default: now",
    )
    seed: int = 0
    map: Path | None = Field(
        default=None,
        description="Road-surface map file read at start for the map methods (pc-map, pc-self-map); "
        "a map that cannot be read is logged and the agent fits planes as without one",
    )
    dgnss: bool | None = Field(default=None, description="Use the base station; default: when present")
    map_wait_s: float = Field(
        default=10.0,
        ge=0.0,
        description="Map methods: wait this long at the first fix for the fusion servers' tiles around it",
    )
    map_radius_m: float = Field(
        default=1500.0,
        ge=100.0,
        le=50000.0,
        description="Map methods: ask the fusion servers for the road map within this distance of the vehicle "
        "(a new box once it is half this from the edge)",
    )
    map_refresh_s: float = Field(
        default=10.0,
        gt=0.0,
        description="Map methods: ask for the tiles that changed around the vehicle this often",
    )
    resend_s: float = Field(
        default=1.0,
        gt=0.0,
        description="Lockstep: re-send the unanswered node message after at least this (longer when answers take longer)",
    )
    lease_ms: int = Field(default=2000, ge=500, description="Zenoh lease: how fast a dead peer is noticed")
    nmea_port: int | None = Field(
        default=None,
        ge=0,
        le=65535,
        description="Serve this vehicle's fused solutions as NMEA 0183 GGA + GST + RMC over TCP on "
        "127.0.0.1 at this port (0: any free port, logged at start); default: no NMEA",
    )
    log_level: LogLevel = "INFO"


class LoadgenSettings(ServiceSettings, RegionOptions):
    """`coplane loadgen` (env COPLANE_LOADGEN_*, TOML table [loadgen], or --flags): many vehicles of
    a recording in one process (services/vehicle_agent/loadgen.py)."""

    model_config = SettingsConfigDict(env_prefix="COPLANE_LOADGEN_", extra="ignore")
    toml_table: str = "loadgen"

    recording: Path = Field(description="Fleet recording directory (fleet.toml)")
    vehicles: int = Field(default=0, ge=0, description="Only the first N vehicles; 0: all")
    method: str = "pc"
    fleet: str | None = None
    connect: list[str] = Field(default_factory=lambda: ["tcp/127.0.0.1:7447"])
    pace: Pace = "lockstep"
    speed: float = Field(default=1.0, gt=0.0, description="Realtime replay speed factor")
    seed: int = 0
    resend_s: float = Field(
        default=1.0,
        gt=0.0,
        description="Lockstep: re-send unanswered node messages after at least this (longer when answers take longer), doubling",
    )
    epoch_timeout_s: float = Field(
        default=30.0, gt=0.0, description="Lockstep: give up on an epoch's answers"
    )
    settle_s: float = Field(
        default=3.0,
        gt=0.0,
        description="Lockstep: once some server answered, go on when no answer came for this long",
    )
    lease_ms: int = Field(default=2000, ge=500)
    log_level: LogLevel = "INFO"
