"""The road-surface map (docs/roadmap.md): its tiles in a lon/lat box as GeoJSON, and its changes.

The API reads the map file (`--map`) read-only, per request and in a worker thread: SQLite in WAL
mode lets the fusion server or `coplane map build` write it meanwhile, and a file that is replaced
or damaged is noticed on the next request (503 naming it) without stopping the API.
"""

from __future__ import annotations

import asyncio
import math
from pathlib import Path
from typing import Annotated, Any

from fastapi import APIRouter, HTTPException, Query
from fastapi.responses import JSONResponse

from coplane.errors import CoplaneError
from coplane.roadmap.geojson import tiles_geojson
from coplane.store.roadmap_db import RoadMapDb

from ..deps import MapPathDep
from . import problems

router = APIRouter(tags=["map"])
GEOJSON = "application/geo+json"
MAX_BOX_DEG = 0.5  # about 55 km of latitude: one request scans at most a few thousand grid rows


def parse_bbox(text: str) -> tuple[float, float, float, float]:
    """ "min_lon,min_lat,max_lon,max_lat" in degrees; ValueError naming what is wrong."""
    parts = text.split(",")
    if len(parts) != 4:
        raise ValueError(f"bbox needs 4 numbers min_lon,min_lat,max_lon,max_lat, got {len(parts)}")
    try:
        v = [float(p) for p in parts]
    except ValueError:
        raise ValueError(f"bbox {text!r}: not numbers") from None
    if not all(math.isfinite(x) for x in v):
        raise ValueError("bbox: every number must be finite")
    lo_lon, lo_lat, hi_lon, hi_lat = v
    if not (-180.0 <= lo_lon <= 180.0 and -180.0 <= hi_lon <= 180.0):
        raise ValueError("bbox: longitudes must lie in [-180, 180]")
    if not (-90.0 <= lo_lat <= 90.0 and -90.0 <= hi_lat <= 90.0):
        raise ValueError("bbox: latitudes must lie in [-90, 90]")
    if not (lo_lon < hi_lon and lo_lat < hi_lat):
        raise ValueError("bbox: min must be below max for both longitude and latitude")
    if hi_lon - lo_lon > MAX_BOX_DEG or hi_lat - lo_lat > MAX_BOX_DEG:
        raise ValueError(f"bbox: at most {MAX_BOX_DEG} degrees on a side")
    return lo_lon, lo_lat, hi_lon, hi_lat


def _read(path: Path | None, what: Any) -> Any:
    if path is None:
        raise HTTPException(404, "no road map configured: start the API with --map FILE (COPLANE_API_MAP)")
    if not path.exists():
        raise HTTPException(404, f"road map {path} does not exist yet (the fusion server creates it)")
    try:
        with RoadMapDb(path, readonly=True) as db:
            return what(db)
    except CoplaneError as exc:
        raise HTTPException(503, f"road map {path} unavailable: {exc}") from None


@router.get(
    "/map/tiles",
    responses={
        200: {
            "description": "Tiles meeting the box, as a GeoJSON FeatureCollection",
            "content": {GEOJSON: {}},
        },
        **problems(404, 422, 503),
    },
    summary="Road-map tiles in a lon/lat box (GeoJSON polygons with height, sigma, passes)",
)
async def get_tiles(
    path: MapPathDep,
    bbox: Annotated[
        str, Query(description="min_lon,min_lat,max_lon,max_lat in degrees (at most 0.5 per side)")
    ],
) -> JSONResponse:
    try:
        box = parse_bbox(bbox)
    except ValueError as exc:
        raise HTTPException(422, str(exc)) from None

    def tiles(db: RoadMapDb) -> dict[str, Any]:
        return tiles_geojson(db.tiles_in_bbox(*box), db.config)

    fc = await asyncio.to_thread(_read, path, tiles)
    return JSONResponse(fc, media_type=GEOJSON)


@router.get(
    "/map/changes",
    responses={200: {"description": "The newest changes first"}, **problems(404, 422, 503)},
    summary="Road-map tiles the map re-learned after their road changed",
)
async def get_changes(
    path: MapPathDep,
    limit: Annotated[int, Query(ge=1, le=1000, description="At most this many, newest first")] = 100,
) -> JSONResponse:
    changes = await asyncio.to_thread(_read, path, lambda db: db.changes(limit))
    return JSONResponse({"changes": changes})
