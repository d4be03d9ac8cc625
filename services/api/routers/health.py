"""Liveness (the process answers) and readiness (bus up, fusion server alive, solutions flowing)."""

from __future__ import annotations

from fastapi import APIRouter
from fastapi.responses import JSONResponse, Response

from .. import views
from ..deps import BusDep, NowDep, StateDep
from ..models import Health, Readiness

router = APIRouter(tags=["health"])


@router.get("/healthz", response_model=Health, summary="Liveness: the process serves HTTP")
async def healthz(state: StateDep, now: NowDep) -> Health:
    return views.health(state, now)


@router.get(
    "/readyz",
    response_model=Readiness,
    responses={503: {"model": Readiness, "description": "Not ready; `reasons` says why"}},
    summary="Readiness: 503 until the bus is connected, a fusion server is alive and a solution arrived",
)
async def readyz(state: StateDep, bus: BusDep, now: NowDep) -> Response | Readiness:
    r = views.readiness(state, now, bus.connected())
    if not r.ready:
        return JSONResponse(r.model_dump(mode="json"), status_code=503)
    return r
