"""The FastAPI application: `create_app(settings, bus=None)`.

The bus is injectable: `None` opens a Zenoh session in the lifespan; tests pass a `LocalBus` and
feed `app.state.ingest` (or `app.state.fleet`) directly. Read-only: there is no endpoint that
changes the fleet, so there is no token to configure. Errors are RFC 7807 problem details.
"""

from __future__ import annotations

import asyncio
import copy
import logging
import time
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from http import HTTPStatus
from typing import Any

from fastapi import FastAPI, Request
from fastapi.encoders import jsonable_encoder
from fastapi.exceptions import RequestValidationError
from fastapi.middleware.cors import CORSMiddleware
from fastapi.openapi.utils import get_openapi
from fastapi.responses import JSONResponse
from pydantic.json_schema import models_json_schema
from starlette.exceptions import HTTPException as StarletteHTTPException

from coplane import __version__
from coplane.evaluate.rtk_reference import use_rtk_truth
from coplane.evaluate.truth import use_truth_files
from coplane.gtime import GpsTime
from coplane.recording.manifest import load_manifest
from coplane.recording.reader import open_recording
from coplane.replay import fleet_id

from .bus_client import Bus, Ingest, ZenohBus
from .history import check_history, open_history
from .hub import StreamHub
from .map_reader import MapReader
from .models import GeoJsonFeatureCollection, Problem, StreamEvent
from .routers import accuracy, dashboard, health, metrics, planes, regions, stream, vehicles
from .routers import map as road_map
from .settings import ApiSettings
from .state import FleetState

log = logging.getLogger("coplane.api")
PROBLEM_JSON = "application/problem+json"

DESCRIPTION = """Read-only HTTP view of one coplane fleet: latest vehicle states, tracks, road-plane
status, running accuracy against truth, live solutions (Server-Sent Events), Prometheus metrics
and a dashboard at `/`. Errors are RFC 7807 problem details (`application/problem+json`)."""


def _fleet_of(settings: ApiSettings) -> tuple[str, list[str], dict[str, dict[GpsTime, Any]]]:
    """Fleet id, known vehicles and truth (vehicle -> {nominal epoch: ECEF}) from the settings."""
    if settings.recording is None:
        assert settings.fleet is not None
        return settings.fleet, [], {}
    man = load_manifest(settings.recording)
    rec = open_recording(settings.recording)
    if settings.truth == "rtk":
        log.info("truth: %s", use_rtk_truth(rec))
    elif settings.truth_dir is not None:
        log.info("truth: %s", use_truth_files(rec, settings.truth_dir))
    truth = {v.id: dict(rec.truth_at(v.id)) for v in man.vehicles}
    return settings.fleet or fleet_id(man.name), [v.id for v in man.vehicles], truth


def problem(request: Request, status: int, detail: Any = None, **extra: Any) -> JSONResponse:
    try:
        title = HTTPStatus(status).phrase
    except ValueError:
        title = "Error"
    body = Problem(
        title=title,
        status=status,
        detail=None if detail is None else str(detail),
        instance=request.url.path,
        **extra,
    )
    return JSONResponse(body.model_dump(mode="json", exclude_none=True), status, media_type=PROBLEM_JSON)


async def _http_problem(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, StarletteHTTPException)
    resp = problem(request, exc.status_code, exc.detail)
    if exc.headers:
        resp.headers.update(exc.headers)
    return resp


async def _validation_problem(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, RequestValidationError)
    errors = [
        {k: v for k, v in e.items() if k in ("loc", "msg", "type")} for e in jsonable_encoder(exc.errors())
    ]
    return problem(request, 422, "request parameters are invalid", errors=errors)


async def _unhandled(request: Request, exc: Exception) -> JSONResponse:
    log.exception("unhandled error", extra={"path": request.url.path})
    return problem(request, 500, "internal error (logged)")


def _openapi(app: FastAPI) -> Callable[[], dict[str, Any]]:
    """FastAPI's schema, with problem+json error bodies and the models only named in `responses`."""

    def build() -> dict[str, Any]:
        if app.openapi_schema:
            return app.openapi_schema
        spec = get_openapi(
            title=app.title, version=app.version, description=app.description, routes=app.routes
        )
        comps = spec.setdefault("components", {}).setdefault("schemas", {})
        _, extra = models_json_schema(
            [(GeoJsonFeatureCollection, "serialization"), (StreamEvent, "serialization")],
            ref_template="#/components/schemas/{model}",
        )
        for name, sch in extra.get("$defs", {}).items():
            comps.setdefault(name, sch)
        problem_ref = {"$ref": "#/components/schemas/Problem"}
        for ops in spec.get("paths", {}).values():
            for op in ops.values():
                for code, resp in op.get("responses", {}).items():
                    if not code.startswith(("4", "5")):
                        continue
                    refs = [c.get("schema", {}).get("$ref", "") for c in resp.get("content", {}).values()]
                    if any(r.endswith(("/Problem", "/HTTPValidationError")) for r in refs):
                        resp["content"] = {PROBLEM_JSON: {"schema": problem_ref}}
        sse = spec["paths"]["/stream"]["get"]["responses"]["200"]["content"]["text/event-stream"]
        sse.pop("schema", None)  # the body is a stream; each event's `data` is a StreamEvent
        # a copy: FastAPI may hand out its module-level SSE schema dict here
        item = sse["itemSchema"] = copy.deepcopy(sse.get("itemSchema", {"type": "object", "properties": {}}))
        item["properties"]["data"] = {
            "type": "string",
            "contentMediaType": "application/json",
            "contentSchema": {"$ref": "#/components/schemas/StreamEvent"},
        }
        for unused in ("HTTPValidationError", "ValidationError"):
            comps.pop(unused, None)
        app.openapi_schema = spec
        return spec

    return build


def create_app(
    settings: ApiSettings,
    bus: Bus | None = None,
    *,
    state: FleetState | None = None,
    clock: Callable[[], float] = time.time,
) -> FastAPI:
    """The app; `bus=None` opens Zenoh in the lifespan, `state` replaces the one built from settings."""
    if state is None:
        fleet, known, truth = _fleet_of(settings)
        state = FleetState(
            fleet,
            history_per_vehicle=settings.history_per_vehicle,
            max_vehicles=settings.max_vehicles,
            accuracy_window=settings.accuracy_window,
            stale_after_s=settings.stale_after_s,
            truth=truth,
            known_vehicles=known,
            started=clock(),
            regions=settings.region_config() if settings.regions else None,
        )
    fleet = state.fleet
    if bus is None:
        check_history(settings, fleet)  # a corrupt log fails here, named, not in the lifespan
    hub = StreamHub(settings.stream_max_clients, settings.stream_queue)
    ingest = Ingest(state, hub, settings.max_pending, clock)
    the_bus: Bus = bus if bus is not None else ZenohBus(fleet, settings.connect, settings.lease_ms)
    map_reader = MapReader()

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        ingest.bind(asyncio.get_running_loop())
        # the accepted-solutions log: loaded before subscribing (an injected bus means a test: none)
        history = open_history(settings, state) if bus is None else None
        the_bus.start(ingest)
        log.info(
            "api started", extra={"fleet": fleet, "vehicles": len(state.vehicles), "truth": len(state.truth)}
        )
        try:
            yield
        finally:
            hub.close()
            await asyncio.to_thread(the_bus.close)
            if history is not None:
                history.close()
            await asyncio.to_thread(map_reader.close)
            log.info("api stopped", extra={"solutions": state.solutions})

    app = FastAPI(
        title="coplane API",
        version=__version__,
        description=DESCRIPTION,
        lifespan=lifespan,
    )
    app.state.settings = settings
    app.state.fleet = state
    app.state.hub = hub
    app.state.ingest = ingest
    app.state.bus = the_bus
    app.state.clock = clock
    app.state.map_reader = map_reader
    app.state.registry = metrics.make_registry(metrics.FleetCollector(state, ingest, hub, the_bus, clock))
    app.state.registry.register(map_reader)
    app.state.dashboard_html = dashboard.load_dashboard()
    for r in (vehicles, planes, accuracy, stream, health, metrics, dashboard, road_map, regions):
        app.include_router(r.router)
    app.add_exception_handler(StarletteHTTPException, _http_problem)
    app.add_exception_handler(RequestValidationError, _validation_problem)
    app.add_exception_handler(Exception, _unhandled)
    if settings.cors_origins:
        app.add_middleware(
            CORSMiddleware, allow_origins=settings.cors_origins, allow_methods=["GET"], allow_headers=["*"]
        )
    app.openapi = _openapi(app)  # type: ignore[method-assign]
    return app
