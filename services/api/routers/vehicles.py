"""Vehicles: latest state per vehicle and its bounded track (JSON, GeoJSON, GPX or RTKLIB .pos)."""

from __future__ import annotations

from typing import Annotated, Literal

from fastapi import APIRouter, HTTPException, Path, Query
from fastapi.responses import JSONResponse, Response

from coplane.ids import VEHICLE_ID_PATTERN

from .. import views
from ..deps import NowDep, StateDep
from ..models import Track, VehicleDetail, VehicleList
from . import problems

router = APIRouter(tags=["vehicles"])

VehicleIdPath = Annotated[str, Path(pattern=VEHICLE_ID_PATTERN, description="Vehicle id as on the bus")]
GEOJSON = "application/geo+json"
GPX = "application/gpx+xml"
POS = "text/plain"  # RTKLIB's solution files have no media type of their own
# the bounds of a track request, the same for every track format
SinceQuery = Annotated[
    float | None,
    Query(
        allow_inf_nan=False,
        description="Only points after this GPS time (seconds since the GPS epoch: week*604800+tow)",
    ),
]
LimitQuery = Annotated[int | None, Query(ge=1, le=1_000_000, description="At most the last N points")]


def _unknown(vid: str) -> HTTPException:
    return HTTPException(404, f"vehicle {vid!r} is not known to this API")


@router.get("/vehicles", response_model=VehicleList, summary="Latest state of every vehicle")
async def list_vehicles(state: StateDep, now: NowDep) -> VehicleList:
    return views.vehicle_list(state, now)


@router.get(
    "/vehicles/{vehicle_id}",
    response_model=VehicleDetail,
    responses=problems(404, 422),
    summary="Latest state of one vehicle with covariance, plane and message counters",
)
async def get_vehicle(vehicle_id: VehicleIdPath, state: StateDep, now: NowDep) -> VehicleDetail:
    out = views.vehicle_detail(state, vehicle_id, now)
    if out is None:
        raise _unknown(vehicle_id)
    return out


@router.get(
    "/vehicles/{vehicle_id}/track",
    response_model=Track,
    responses={
        200: {
            "description": "The track; `format=geojson` gives a GeoJSON FeatureCollection",
            "content": {GEOJSON: {"schema": {"$ref": "#/components/schemas/GeoJsonFeatureCollection"}}},
        },
        **problems(404, 422),
    },
    summary="Recent positions of one vehicle (bounded history)",
)
async def get_track(
    vehicle_id: VehicleIdPath,
    state: StateDep,
    since: SinceQuery = None,
    limit: LimitQuery = None,
    format: Annotated[Literal["json", "geojson"], Query(description="json or geojson")] = "json",
) -> Response | Track:
    if format == "geojson":
        return await get_track_geojson(vehicle_id, state, since, limit)
    tr = views.track(state, vehicle_id, since, limit)
    if tr is None:
        raise _unknown(vehicle_id)
    return tr


@router.get(
    "/vehicles/{vehicle_id}/track.geojson",
    responses={
        200: {
            "description": "The track as a GeoJSON FeatureCollection ([lon, lat, ellipsoidal height])",
            "content": {GEOJSON: {"schema": {"$ref": "#/components/schemas/GeoJsonFeatureCollection"}}},
        },
        **problems(404, 422),
    },
    response_class=Response,
    summary="Recent positions of one vehicle as GeoJSON (for GIS tools)",
)
async def get_track_geojson(
    vehicle_id: VehicleIdPath,
    state: StateDep,
    since: SinceQuery = None,
    limit: LimitQuery = None,
) -> Response:
    fc = views.track_geojson(state, vehicle_id, since, limit)
    if fc is None:
        raise _unknown(vehicle_id)
    return JSONResponse(fc.model_dump(mode="json"), media_type=GEOJSON)


@router.get(
    "/vehicles/{vehicle_id}/track.gpx",
    responses={
        200: {"description": "The track as GPX 1.1 (UTC times, ellipsoidal heights)", "content": {GPX: {}}},
        **problems(404, 422),
    },
    response_class=Response,
    summary="Recent positions of one vehicle as GPX (for GPS tools)",
)
async def get_track_gpx(
    vehicle_id: VehicleIdPath,
    state: StateDep,
    since: SinceQuery = None,
    limit: LimitQuery = None,
) -> Response:
    return _track_file(views.track_gpx(state, vehicle_id, since, limit), vehicle_id, GPX)


@router.get(
    "/vehicles/{vehicle_id}/track.pos",
    responses={
        200: {
            "description": "The track in RTKLIB's .pos layout (GPST, WGS-84 latitude / longitude /"
            " ellipsoidal height; Q 4 DGNSS, 5 standalone, 7 carried without a GNSS fix; ns the"
            " pseudoranges kept; the reported covariance; the corrections' age)",
            "content": {POS: {}},
        },
        **problems(404, 422),
    },
    response_class=Response,
    summary="Recent positions of one vehicle as an RTKLIB .pos file (for RTKPLOT)",
)
async def get_track_pos(
    vehicle_id: VehicleIdPath,
    state: StateDep,
    since: SinceQuery = None,
    limit: LimitQuery = None,
) -> Response:
    return _track_file(views.track_pos(state, vehicle_id, since, limit), vehicle_id, POS)


def _track_file(text: str | None, vehicle_id: str, media_type: str) -> Response:
    """A track rendered as a file other tools read; 404 when the vehicle is unknown (None)."""
    if text is None:
        raise _unknown(vehicle_id)
    return Response(text, media_type=media_type)
