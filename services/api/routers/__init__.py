"""HTTP routers, one module per concern; they read the app's state and never touch the bus."""

from __future__ import annotations

from typing import Any

from fastapi import Request

from ..bus_client import Bus, Ingest
from ..hub import StreamHub
from ..models import Problem
from ..state import FleetState


def fleet_state(request: Request) -> FleetState:
    return request.app.state.fleet  # type: ignore[no-any-return]


def hub(request: Request) -> StreamHub:
    return request.app.state.hub  # type: ignore[no-any-return]


def ingest(request: Request) -> Ingest:
    return request.app.state.ingest  # type: ignore[no-any-return]


def bus(request: Request) -> Bus:
    return request.app.state.bus  # type: ignore[no-any-return]


def now(request: Request) -> float:
    return float(request.app.state.clock())


def problems(*codes: int) -> dict[int | str, dict[str, Any]]:
    """OpenAPI entries for error responses (the app rewrites them to application/problem+json)."""
    text = {
        404: "Unknown vehicle",
        422: "Invalid parameters",
        503: "Unavailable (too many clients or shutting down)",
    }
    return {c: {"model": Problem, "description": text.get(c, "Error")} for c in codes}
