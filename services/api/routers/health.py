"""Liveness (the process answers) and readiness (bus up, fusion server alive, solutions flowing)."""

from __future__ import annotations

from fastapi import APIRouter, Request
from fastapi.responses import JSONResponse, Response

from ..models import Health, Readiness
from . import bus, fleet_state, now

router = APIRouter(tags=["health"])


@router.get("/healthz", response_model=Health, summary="Liveness: the process serves HTTP")
async def healthz(request: Request) -> Health:
    return fleet_state(request).health(now(request))


@router.get(
    "/readyz",
    response_model=Readiness,
    responses={503: {"model": Readiness, "description": "Not ready; `reasons` says why"}},
    summary="Readiness: 503 until the bus is connected, a fusion server is alive and a solution arrived",
)
async def readyz(request: Request) -> Response | Readiness:
    r = fleet_state(request).readiness(now(request), bus(request).connected())
    if not r.ready:
        return JSONResponse(r.model_dump(mode="json"), status_code=503)
    return r
