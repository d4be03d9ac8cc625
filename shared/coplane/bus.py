"""Small Zenoh helpers: the versioned key space, session configs, and message (de)coding.

Key space (docs/bus.md):
    coplane/v1/<fleet>/vehicle/<id>/node        NodeMessage, vehicle -> server
    coplane/v1/<fleet>/solution                 SolutionMessage, server -> vehicles, API
    coplane/v1/<fleet>/diagnostics              DiagnosticsMessage, server -> API
    coplane/v1/<fleet>/alive/<role>/<id>        liveliness tokens (role: agent | fusion | api)
Fleet and vehicle ids are their own chunks, so `coplane/v1/<fleet>/vehicle/*/node` selects all
vehicles and a router ACL can limit a vehicle to its own keys.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, TypeVar

import zenoh
from pydantic import BaseModel, ValidationError

KEY_ROOT = "coplane/v1"
M = TypeVar("M", bound=BaseModel)


@dataclass(frozen=True)
class KeySpace:
    fleet: str

    @property
    def prefix(self) -> str:
        return f"{KEY_ROOT}/{self.fleet}"

    def node(self, vehicle_id: str) -> str:
        return f"{self.prefix}/vehicle/{vehicle_id}/node"

    @property
    def all_nodes(self) -> str:
        return f"{self.prefix}/vehicle/*/node"

    @property
    def solution(self) -> str:
        return f"{self.prefix}/solution"

    @property
    def diagnostics(self) -> str:
        return f"{self.prefix}/diagnostics"

    def alive(self, role: str, ident: str) -> str:
        return f"{self.prefix}/alive/{role}/{ident}"

    def all_alive(self, role: str = "*") -> str:
        return f"{self.prefix}/alive/{role}/*"

    @staticmethod
    def vehicle_of_node_key(key: str) -> str | None:
        """The <id> chunk of a node key, or None if the key is not a node key."""
        parts = key.split("/")
        if len(parts) == 6 and parts[3] == "vehicle" and parts[5] == "node":
            return parts[4]
        return None

    @staticmethod
    def id_of_alive_key(key: str) -> tuple[str, str] | None:
        parts = key.split("/")
        if len(parts) == 6 and parts[3] == "alive":
            return parts[4], parts[5]
        return None


def session_config(
    mode: str = "client",
    connect: Sequence[str] = (),
    listen: Sequence[str] = (),
    wait_for_router: bool = True,
    lease_ms: int | None = None,
) -> zenoh.Config:
    """A Zenoh config with multicast scouting off (it does not cross Docker bridges anyway).

    `wait_for_router`: a client retries forever instead of failing at once when no router is up,
    so services can start in any order and survive router restarts.
    """
    c = zenoh.Config()
    c.insert_json5("mode", json.dumps(mode))
    c.insert_json5("scouting/multicast/enabled", "false")
    if connect:
        c.insert_json5("connect/endpoints", json.dumps(list(connect)))
        if wait_for_router and mode != "router":
            c.insert_json5("connect/timeout_ms", "-1")
            c.insert_json5("connect/exit_on_failure", "false")
    if listen:
        c.insert_json5("listen/endpoints", json.dumps(list(listen)))
    if lease_ms is not None:
        c.insert_json5("transport/link/tx/lease", str(lease_ms))
        c.insert_json5("transport/link/tx/keep_alive", "4")
    return c


def open_router(listen: Sequence[str]) -> zenoh.Session:
    """A Zenoh router inside this Python process (tests and `coplane fleet` use it)."""
    return zenoh.open(session_config("router", listen=listen))


def encode(msg: BaseModel) -> bytes:
    return msg.model_dump_json(by_alias=True).encode()


class BadMessage(Exception):
    """A payload that failed validation; `kind` is a stable slug for metrics."""

    def __init__(self, kind: str, reason: str) -> None:
        super().__init__(f"{kind}: {reason}")
        self.kind = kind
        self.reason = reason


def decode(model: type[M], payload: bytes, max_bytes: int = 1 << 20) -> M:
    """Validate a payload into `model`; raises BadMessage with a short reason, never anything else."""
    if len(payload) > max_bytes:
        raise BadMessage("too-large", f"{len(payload)} bytes > {max_bytes}")
    try:
        return model.model_validate_json(payload)
    except ValidationError as exc:
        errs = exc.errors()
        if not errs:
            raise BadMessage("invalid-message", str(exc)[:300]) from None
        first = errs[0]
        loc = ".".join(str(x) for x in first["loc"])
        kind = "invalid-json" if first["type"] == "json_invalid" else "invalid-message"
        raise BadMessage(kind, f"{loc}: {first['msg']}"[:300]) from None
    except Exception as exc:  # any parser surprise is still just a bad message
        raise BadMessage("invalid-message", repr(exc)[:300]) from None


def payload_bytes(sample: Any) -> bytes:
    return bytes(sample.payload.to_bytes())
