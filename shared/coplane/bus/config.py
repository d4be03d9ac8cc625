"""Zenoh session configurations for the services, the fleet launcher and the Python router."""

from __future__ import annotations

import json
from collections.abc import Sequence

import zenoh


def session_config(
    mode: str = "client",
    connect: Sequence[str] = (),
    listen: Sequence[str] = (),
    wait_for_router: bool = True,
    lease_ms: int | None = None,
) -> zenoh.Config:
    """A Zenoh config with multicast scouting off (it does not cross Docker bridges anyway).

    `wait_for_router`: a client retries forever instead of failing at once when no router is up,
    so services can start in any order and survive router restarts. `lease_ms`: how fast a dead
    peer's liveliness tokens go away (docs/bus.md, Membership).
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


def router_config(listen: Sequence[str]) -> zenoh.Config:
    """A router listening on `listen` (what `python -m coplane.bus.router` opens)."""
    return session_config("router", listen=listen)
