"""Planes: per vehicle the road-plane status (available / after FE / unavailable and why)."""

from __future__ import annotations

from fastapi import APIRouter

from .. import views
from ..deps import StateDep
from ..models import PlaneList

router = APIRouter(tags=["planes"])


@router.get("/planes", response_model=PlaneList, summary="Road-plane status per vehicle and counts")
async def list_planes(state: StateDep) -> PlaneList:
    return views.planes(state)
