"""Fusion server configuration (env COPLANE_FUSION_*, TOML table [fusion], or --flags)."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import Field
from pydantic_settings import SettingsConfigDict

from coplane.runtime import LogLevel, RegionOptions, ServiceSettings
from coplane.typing import Pace


class FusionSettings(ServiceSettings, RegionOptions):
    model_config = SettingsConfigDict(env_prefix="COPLANE_FUSION_", extra="ignore")
    toml_table: str = "fusion"

    recording: Path = Field(description="The recording's manifest says which vehicles exist")
    method: str = "pc"
    fleet: str | None = None
    connect: list[str] = Field(default_factory=lambda: ["tcp/127.0.0.1:7447"])
    pace: Pace = "lockstep"
    deadline_s: float = Field(
        default=0.5, gt=0.0, description="Realtime: wall seconds after an epoch's first message"
    )
    startup_wait_s: float = Field(
        default=10.0,
        ge=0.0,
        description="Start: wait this long, from the first admitted message, for every vehicle's agent",
    )
    stall_timeout_s: float = Field(
        default=5.0, gt=0.0, description="Lockstep: solve without a silent live vehicle"
    )
    interruption_rate: float = Field(default=0.0, ge=0.0, le=1.0)
    seed: int = 0
    lease_ms: int = Field(default=2000, ge=500)
    diagnostics_period_s: float = Field(default=1.0, gt=0.0)
    db: str = Field(
        default="auto",
        description="Solution log (SQLite): auto = <state dir>/fusion-<fleet>-<method>-<router>.sqlite,"
        " none = off, or a path (docs/reliability/durability.md)",
    )
    map: str = Field(
        default="auto",
        description="Road-surface map (SQLite) this server extends from its solutions and shares on the bus:"
        " auto = <state dir>/map-<fleet>.sqlite, none = off, or a path (one writer per file)",
    )
    map_commit_every_s: float = Field(
        default=10.0, gt=0.0, description="Road map: commit closed passes this often"
    )
    map_snapshot_every_s: float = Field(
        default=60.0, gt=0.0, description="Road map: publish the whole map on the bus this often"
    )
    resume_max_age_s: float = Field(
        default=300.0, ge=0.0, description="Resume from the log only if the crashed server wrote it lately"
    )
    # Admission of node messages (services/fusion_server/admission.py; docs/bus.md, Admission)
    max_ahead_s: float = Field(
        default=30.0, gt=0.0, description="Reject epochs this far ahead of the fleet's current epoch"
    )
    max_pending_epochs: int = Field(
        default=0, ge=0, description="Epochs that may wait to be solved; 0: window + history depth + margin"
    )
    rate_limit_per_s: float = Field(
        default=5.0, ge=0.0, description="Node messages per vehicle per wall second"
    )
    rate_limit_per_epoch: float = Field(
        default=3.0,
        ge=0.0,
        description="Node messages per vehicle per solved epoch (lockstep runs as fast as it solves)",
    )
    rate_limit_burst: float = Field(
        default=240.0, ge=1.0, description="Per vehicle; an agent's cache replays 120 after a server restart"
    )
    spp_residual_max_m: float = Field(
        default=25.0, gt=0.0, description="Median pseudorange residual at a reported SPP fix"
    )
    plane_tilt_max_deg: float = Field(default=30.0, gt=0.0, le=90.0, description="Plane normal vs local up")
    plane_distance_max_m: float = Field(default=150.0, gt=0.0, description="SPP fix to the reported plane")
    plane_policy: Literal["reject", "drop"] = Field(
        default="reject", description="An implausible plane rejects its message, or is dropped from it"
    )
    reject_log_every_s: float = Field(
        default=10.0, ge=0.0, description="At most one rejection log per vehicle and reason this often"
    )
    log_level: LogLevel = "INFO"
    # Regions (docs/scale.md): several servers share a fleet; each needs its own id
    server_id: str = Field(
        default="0",
        pattern=r"^[A-Za-z0-9_-]{1,32}$",
        description="This server's id among the fleet's servers",
    )
    cluster_workers: int = Field(
        default=1,
        ge=1,
        le=64,
        description="Processes that solve the clusters' smoothers (this one and N-1 children; "
        "docs/scale.md, 'Parallel clusters inside one server'); the estimates are the same for any N",
    )
    expected_servers: int = Field(
        default=1, ge=1, le=256, description="Regions: wait (up to startup_wait_s) for this many servers"
    )
