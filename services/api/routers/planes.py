"""Planes: per vehicle the road-plane status (available / after FE / unavailable and why)."""

from __future__ import annotations

from fastapi import APIRouter, Request

from ..models import PlaneList
from . import fleet_state

router = APIRouter(tags=["planes"])


@router.get("/planes", response_model=PlaneList, summary="Road-plane status per vehicle and counts")
async def list_planes(request: Request) -> PlaneList:
    return fleet_state(request).planes()
