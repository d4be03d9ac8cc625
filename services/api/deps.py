"""FastAPI dependencies: what a router may use, as `Annotated` types.

`create_app` puts the store, the stream hub, the bus and the clock on `app.state`; only this
module reads them back, so a router declares `state: StateDep` and never learns where state lives
(tests swap any of them through `create_app`'s arguments). See docs/api.md, "How it is built".
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

from fastapi import Depends, Request
from prometheus_client import CollectorRegistry

from coplane.store import map_path, server_map_path

from .bus_client import Bus
from .hub import StreamHub
from .map_reader import MapReader
from .state import FleetState


def get_state(request: Request) -> FleetState:
    return request.app.state.fleet  # type: ignore[no-any-return]


def get_hub(request: Request) -> StreamHub:
    return request.app.state.hub  # type: ignore[no-any-return]


def get_bus(request: Request) -> Bus:
    return request.app.state.bus  # type: ignore[no-any-return]


def get_now(request: Request) -> float:
    """The app's clock (wall time; tests inject a fixed one), read once per request."""
    return float(request.app.state.clock())


def get_registry(request: Request) -> CollectorRegistry:
    return request.app.state.registry  # type: ignore[no-any-return]


def get_dashboard_html(request: Request) -> str:
    return request.app.state.dashboard_html  # type: ignore[no-any-return]


def get_map_path(request: Request) -> Path | None:
    """The road map file the API serves (settings.map; auto: the fusion server's default; with
    `map_server`, that server's replica of it), or None."""
    settings = request.app.state.settings
    path = map_path(settings.map, request.app.state.fleet.fleet)
    return server_map_path(path, settings.map_server) if path is not None and settings.map_server else path


def get_map_reader(request: Request) -> MapReader:
    return request.app.state.map_reader  # type: ignore[no-any-return]


StateDep = Annotated[FleetState, Depends(get_state)]
HubDep = Annotated[StreamHub, Depends(get_hub)]
BusDep = Annotated[Bus, Depends(get_bus)]
NowDep = Annotated[float, Depends(get_now)]
RegistryDep = Annotated[CollectorRegistry, Depends(get_registry)]
DashboardHtmlDep = Annotated[str, Depends(get_dashboard_html)]
MapPathDep = Annotated[Path | None, Depends(get_map_path)]
MapReaderDep = Annotated[MapReader, Depends(get_map_reader)]
