"""`coplane fleet`: a whole fleet replay as separate processes on this machine (launcher, the
launcher's own listener, the replay itself) and the docker-compose file that starts the same
services. See docs/bus.md."""

from coplane.fleet.collector import Collector
from coplane.fleet.compose import (
    COMPOSE_RECORDING,
    COMPOSE_ROUTER,
    ComposeResult,
    compose_document,
    write_compose,
)
from coplane.fleet.launcher import (
    FleetProcesses,
    ServiceSpec,
    fleet_of,
    fleet_services,
    free_port,
    router_spec,
    wait_for_port,
)
from coplane.fleet.run import FleetOptions, FleetResult, run_fleet

__all__ = [
    "COMPOSE_RECORDING",
    "COMPOSE_ROUTER",
    "Collector",
    "ComposeResult",
    "FleetOptions",
    "FleetProcesses",
    "FleetResult",
    "ServiceSpec",
    "compose_document",
    "fleet_of",
    "fleet_services",
    "free_port",
    "router_spec",
    "run_fleet",
    "wait_for_port",
    "write_compose",
]
