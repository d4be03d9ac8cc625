"""Durable state on an embedded database: the append-only solution log the fusion server, the API
and `coplane fleet --out` keep (docs/reliability/durability.md)."""

from coplane.store.log import (
    APPLICATION_ID,
    SCHEMA_VERSION,
    SolutionLog,
    StoredSolution,
    StoreError,
    Synchronous,
)
from coplane.store.paths import default_state_dir, log_path, map_path, server_map_path

__all__ = [
    "APPLICATION_ID",
    "SCHEMA_VERSION",
    "SolutionLog",
    "StoreError",
    "StoredSolution",
    "Synchronous",
    "default_state_dir",
    "log_path",
    "map_path",
    "server_map_path",
]
