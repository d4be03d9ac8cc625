"""API configuration (env COPLANE_API_*, TOML table [api] of $COPLANE_CONFIG, or --flags).

`coplane fleet` starts the API as `python -m coplane.api --recording DIR --connect '["tcp/..."]'
--port N`, so those three flags are the contract with the launcher and docker-compose.
"""

from __future__ import annotations

from pathlib import Path

from pydantic import Field, model_validator
from pydantic_settings import SettingsConfigDict

from coplane.evaluate.truth import Truth
from coplane.ids import VEHICLE_ID_PATTERN
from coplane.runtime import LogLevel, RegionOptions, ServiceSettings


class ApiSettings(RegionOptions, ServiceSettings):
    model_config = SettingsConfigDict(env_prefix="COPLANE_API_", extra="ignore")
    toml_table: str = "api"

    recording: Path | None = Field(
        default=None, description="Fleet recording: gives the fleet id, the vehicle list and the truth"
    )
    truth: Truth = Field(
        default="recording",
        description="What the accuracy is measured against: the recording's truth files, or RTKLIB's"
        " carrier-phase RTK to the recording's base where it holds (a drive without a surveyed trajectory)",
    )
    truth_dir: Path | None = Field(
        default=None,
        description="A directory of <vehicle>.csv truth files (the recording format's) replacing the"
        " recording's truth: how `coplane fleet --truth rtk` hands over the RTK reference it made once",
    )
    fleet: str | None = Field(
        default=None,
        pattern=VEHICLE_ID_PATTERN,  # a fleet id is a key chunk too, under the same rule
        description="Bus fleet id; default: derived from the recording's name",
    )
    connect: list[str] = Field(
        default_factory=lambda: ["tcp/127.0.0.1:7447"], description="Zenoh router endpoints"
    )
    host: str = "127.0.0.1"
    port: int = Field(default=8000, ge=0, le=65535)
    history_per_vehicle: int = Field(
        default=3600, ge=1, le=1_000_000, description="Track points kept per vehicle (oldest dropped)"
    )
    max_vehicles: int = Field(
        default=256,
        ge=1,
        le=100_000,
        description="Vehicles tracked at most (bounds memory and labels: with the default track length,"
        " 256 x 3600 points x ~0.5 kB is about 0.5 GB at worst)",
    )
    accuracy_window: int = Field(
        default=86_400,
        ge=10,
        le=10_000_000,
        description="Horizontal errors kept per vehicle and method for CEP95 (RMSE/max are all-time)",
    )
    stale_after_s: float = Field(
        default=10.0,
        gt=0.0,
        description="Not ready when no solution arrived for this long while agents are live",
    )
    cors_origins: list[str] = Field(default_factory=list, description="Allowed origins; empty: CORS off")
    stream_max_clients: int = Field(default=32, ge=1, le=10_000, description="Concurrent /stream clients")
    stream_queue: int = Field(
        default=64, ge=1, le=10_000, description="Events buffered per slow /stream client (oldest dropped)"
    )
    max_pending: int = Field(
        default=10_000, ge=10, description="Bus payloads waiting to be decoded before new ones are dropped"
    )
    lease_ms: int = Field(default=2000, ge=500, description="Zenoh lease: how fast a dead peer is noticed")
    db: str = Field(
        default="auto",
        description="Accepted solutions log (SQLite), loaded on start: auto = <state dir>/api-<fleet>-<router>.sqlite,"
        " none = off, or a path (docs/reliability/durability.md)",
    )
    map: str | None = Field(
        default="auto",
        description="Road-surface map (SQLite, read-only) served by /map/tiles and /map/changes: auto = the"
        " fusion server's <state dir>/map-<fleet>.sqlite, none = off, or a path",
    )
    map_server: str | None = Field(
        default=None,
        pattern=r"^[A-Za-z0-9_-]{1,32}$",
        description="With several fusion servers by region: read this server's replica of the map"
        " (<stem>.<server>.sqlite beside it; each replica is the whole map, docs/scale.md)",
    )
    access_log: bool = False
    log_level: LogLevel = "INFO"

    @model_validator(mode="after")
    def _fleet_known(self) -> ApiSettings:
        if self.recording is None and self.fleet is None:
            raise ValueError("give --recording or --fleet: the API must know which fleet to watch")
        if self.truth_dir is not None and (self.truth != "recording" or self.recording is None):
            raise ValueError(
                "--truth_dir replaces a --recording's truth files: give it with --recording, without --truth"
            )
        return self
