"""The road-surface map (docs/roadmap.md): its tiles in a lon/lat box as GeoJSON, and its changes.

The API reads the map file (`--map`) through one cached read-only connection (`..map_reader`) in a
worker thread: SQLite in WAL mode lets the fusion server or `coplane map build` write it meanwhile,
and a file that is replaced or damaged is noticed on the next request (503 naming it) without
stopping the API. Every answer of these endpoints, errors included, is counted for /metrics.
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import Callable, Coroutine
from typing import Annotated, Any

from fastapi import APIRouter, HTTPException, Query, Request, Response
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from fastapi.routing import APIRoute
from starlette.exceptions import HTTPException as StarletteHTTPException

from coplane.roadmap.geojson import tiles_geojson
from coplane.roadmap.grid import row_col_ranges
from coplane.store.roadmap_db import RoadMapDb

from ..deps import MapPathDep, MapReaderDep
from ..map_reader import MapError, MapReader
from . import problems

GEOJSON = "application/geo+json"
MAX_BOX_DEG = 0.5  # about 55 km of latitude
MAX_LAT_DEG = 85.0  # the map grid's limit (coplane.roadmap.grid): columns degenerate nearer the poles
MAX_ROWS = 6000  # grid rows one box may scan (one index range each): 0.5 deg at 20 m tiles is ~2800
MAX_TILES = 10_000  # stored tiles one answer may hold (about 5 MB of GeoJSON, well under a second)


class _CountedRoute(APIRoute):
    """Counts every answer of the route by status, parameter validation errors included."""

    def get_route_handler(self) -> Callable[[Request], Coroutine[Any, Any, Response]]:
        handler = super().get_route_handler()
        path = self.path

        async def counted(request: Request) -> Response:
            reader: MapReader = request.app.state.map_reader
            status = 500
            try:
                response = await handler(request)
                status = response.status_code
                return response
            except StarletteHTTPException as exc:
                status = exc.status_code
                raise
            except RequestValidationError:
                status = 422
                raise
            finally:
                reader.count(path, status)

        return counted


router = APIRouter(tags=["map"], route_class=_CountedRoute)


def parse_bbox(text: str) -> tuple[float, float, float, float]:
    """ "min_lon,min_lat,max_lon,max_lat" in degrees; ValueError naming what is wrong."""
    parts = text.split(",")
    if len(parts) != 4:
        raise ValueError(f"bbox needs 4 numbers min_lon,min_lat,max_lon,max_lat, got {len(parts)}")
    try:
        v = [float(p) for p in parts]
    except ValueError:
        raise ValueError(f"bbox {text[:100]!r}: not numbers") from None
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
    if max(abs(lo_lat), abs(hi_lat)) >= MAX_LAT_DEG:
        raise ValueError(f"bbox: the road map grid covers latitudes within +-{MAX_LAT_DEG:g} degrees only")
    return lo_lon, lo_lat, hi_lon, hi_lat


class _TooBig(ValueError):
    """The box is valid but too large for this map (its tile size, its stored tiles): 422."""


def _tiles_in(db: RoadMapDb, box: tuple[float, float, float, float]) -> dict[str, Any]:
    size = db.config.tile_size_m
    try:
        ranges = row_col_ranges(*box, size)
    except ValueError as exc:  # the box reaches where the grid is undefined
        raise _TooBig(f"bbox: {exc}") from None
    if len(ranges) > MAX_ROWS:
        raise _TooBig(
            f"bbox: spans {len(ranges)} grid rows of this map's {size:g} m tiles, at most {MAX_ROWS};"
            " ask for a smaller box"
        )
    n = 0
    for row, c0, c1 in ranges:  # count first (index only), so a dense box is refused cheaply
        n += db.db.execute(
            "SELECT count(*) FROM tiles WHERE row = ? AND col BETWEEN ? AND ?", (row, c0, c1)
        ).fetchall()[0][0]
        if n > MAX_TILES:
            raise _TooBig(f"bbox: holds more than {MAX_TILES} stored tiles; ask for a smaller box")
    return tiles_geojson(db.tiles_in_bbox(*box), db.config)


async def _read(reader: MapReader, path: MapPathDep, fn: Callable[[RoadMapDb], Any]) -> Any:
    try:
        return await asyncio.to_thread(reader.read, path, fn)
    except MapError as exc:
        raise HTTPException(exc.status, exc.detail) from None
    except _TooBig as exc:
        raise HTTPException(422, str(exc)) from None


@router.get(
    "/map/tiles",
    responses={
        200: {
            "description": "Stored tiles meeting the box, as a GeoJSON FeatureCollection (one Polygon each)",
            "content": {GEOJSON: {}},
        },
        **problems(404, 422, 503),
    },
    summary="Road-map tiles in a lon/lat box (GeoJSON polygons with height, sigma, passes)",
)
async def get_tiles(
    path: MapPathDep,
    reader: MapReaderDep,
    bbox: Annotated[
        str,
        Query(
            max_length=200,
            description="min_lon,min_lat,max_lon,max_lat in degrees (at most 0.5 per side, |lat| < 85)",
        ),
    ],
) -> JSONResponse:
    try:
        box = parse_bbox(bbox)
    except ValueError as exc:
        raise HTTPException(422, str(exc)) from None
    fc = await _read(reader, path, lambda db: _tiles_in(db, box))
    return JSONResponse(fc, media_type=GEOJSON)


@router.get(
    "/map/changes",
    responses={200: {"description": "The newest changes first"}, **problems(404, 422, 503)},
    summary="Road-map tiles the map re-learned after their road changed",
)
async def get_changes(
    path: MapPathDep,
    reader: MapReaderDep,
    limit: Annotated[int, Query(ge=1, le=1000, description="At most this many, newest first")] = 100,
) -> JSONResponse:
    changes = await _read(reader, path, lambda db: db.changes(limit))
    return JSONResponse({"changes": changes})
