"""The fleet's processes: which services a replay starts (`fleet_services`), and starting,
watching and stopping them on this machine (`FleetProcesses`).

docker-compose.yml is generated from the same service list (coplane.fleet.compose), so
`coplane fleet` and docker-compose start the same processes.
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from coplane.allocator import allocator_env
from coplane.bus.security import API, FUSION, ROUTER, BusSecurity, server_identity, vehicle_identity
from coplane.errors import CoplaneError
from coplane.recording.manifest import load_manifest
from coplane.replay import fleet_id

log = logging.getLogger("coplane.fleet")

ROUTER_MODULE = "coplane.bus.router"
FUSION_MODULE = "coplane.fusion_server"
AGENT_MODULE = "coplane.vehicle_agent"
API_MODULE = "coplane.api"
# stopping the fleet: the services get SIGTERM together and STOP_GRACE_S (coplane.runtime) to end
# cleanly, so the whole fleet is gone well within the 5 s a Ctrl-C may take
STOP_TIMEOUT_S = 4.0


def free_port() -> int:
    """A TCP port nobody listens on right now (tests and `--port 0`)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


API_SERVICE = "api"  # the API's name among the fleet's services (and in docker-compose)


def wait_for_port(port: int, timeout: float = 15.0, proc: subprocess.Popen[bytes] | None = None) -> None:
    """Return once something listens on 127.0.0.1:`port` (the router is up); CoplaneError at
    once if `proc`, the process that should listen there, has exited."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if proc is not None and (rc := proc.poll()) is not None:
            raise CoplaneError(
                f"the process that should listen on port {port} (pid {proc.pid}) exited with code {rc}"
                " before it did (--logs DIR keeps its output)"
            )
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return
        time.sleep(0.05)
    raise TimeoutError(f"nothing listens on 127.0.0.1:{port} after {timeout} s")


@dataclass
class ServiceSpec:
    """One process of the fleet: the same list drives the launcher and is checked against compose."""

    name: str  # compose service name
    module: str  # python -m <module>
    args: list[str] = field(default_factory=list)
    identity: str = ""  # its bus identity: the certificate it connects with (coplane.bus.security)


def fleet_of(recording: Path) -> tuple[str, list[str]]:
    """(bus fleet id, vehicle ids) of a recording, from its manifest alone."""
    man = load_manifest(recording)
    return fleet_id(man.name), [v.id for v in man.vehicles]


def router_spec(
    port: int, secure: bool = False, fleet: str | None = None, mesh: Sequence[int] = (), index: int = 1
) -> ServiceSpec:
    """The Python router on 127.0.0.1:`port`; `secure`: TLS (its ACL then comes from the certificates
    folder in its environment), `fleet`: grant only that fleet's keys; `mesh`: the ports of the
    routers it connects to; `index` > 1 names the mesh's further routers zenoh-router-2, ..."""
    scheme = "tls" if secure else "tcp"
    args = ["--listen", f"{scheme}/127.0.0.1:{port}"]
    if fleet is not None:
        args += ["--fleet", fleet]
    for p in mesh:
        args += ["--connect", f"{scheme}/127.0.0.1:{p}"]
    return ServiceSpec("zenoh-router" if index == 1 else f"zenoh-router-{index}", ROUTER_MODULE, args, ROUTER)


def server_ids(servers: int) -> list[str]:
    """The `--server_id`s of a fleet's fusion servers with regions (none for a single server);
    each joins the bus as its own identity, `fusion-<id>` (docs/bus.md)."""
    return [f"s{i}" for i in range(1, servers + 1)] if servers > 1 else []


def fusion_name(i: int, servers: int) -> str:
    """The service name of fusion server `i` (1-based) of `servers`."""
    return "fusion-server" if servers == 1 else f"fusion-server-{i}"


def map_args(map_path: Path | str | None) -> list[str]:
    """The `--map` arguments of a server or the API: "auto", the service's own default (its state
    directory); None, no map. With several servers each keeps its own replica beside the file
    (docs/scale.md, "The road map across servers")."""
    return [] if map_path == "auto" else ["--map", str(map_path) if map_path is not None else "none"]


def api_spec(
    recording: Path,
    connect: str,
    api_port: int = 8000,
    road_map: Sequence[str] = (),
    servers: int = 1,
    truth_dir: Path | None = None,
) -> ServiceSpec:
    """The API's process. The launcher starts it on its own, before the others, and waits until it
    listens (it has then subscribed), so that it sees every epoch. `road_map`: `map_args`'s
    arguments; `truth_dir`: truth files replacing the recording's (`--truth rtk`)."""
    return ServiceSpec(
        API_SERVICE,
        API_MODULE,
        [
            "--recording",
            str(recording),
            "--connect",
            f'["{connect}"]',
            "--port",
            str(api_port),
            *road_map,
            *(["--map_server", "s1"] if servers > 1 else []),  # a whole replica (docs/scale.md)
            *(["--regions", "true"] if servers > 1 else []),  # each server speaks of its regions
            *(["--truth_dir", str(truth_dir)] if truth_dir is not None else []),
        ],
        API,
    )


def fleet_services(
    recording: Path,
    method: str,
    pace: str,
    speed: float,
    connect: str,
    vehicles: Sequence[str],
    api: bool,
    api_port: int = 8000,
    seed: int = 0,
    interruption: float = 0.0,
    start_unix_s: float | None = None,
    map_path: Path | str | None = "auto",
    servers: int = 1,
    routers: Sequence[str] = (),
    cluster_workers: int = 1,
    truth_dir: Path | None = None,
) -> list[ServiceSpec]:
    """The fleet's processes. `start_unix_s`: realtime agents' shared wall-clock origin. `map_path`:
    a road-surface map the fusion server (its one writer) extends and shares on the bus, where the
    agents of a map method take it from (they need no access to the file); None: no map. `servers` > 1: that
    many fusion servers share the fleet by region (docs/scale.md), named fusion-server-1..N.
    `routers`: the endpoints of a router mesh; the servers and the agents take them in turn (the
    API takes `connect`). `cluster_workers` > 1: each server solves its clusters on that many
    processes. `truth_dir`: truth files replacing the recording's for the API (`--truth rtk` makes
    RTKLIB's reference once, in the launcher, and hands it over there)."""
    rec = str(recording)
    mesh = list(routers) or [connect]

    def via(k: int) -> str:
        return f'["{mesh[k % len(mesh)]}"]'

    start = ["--start_unix_s", f"{start_unix_s:.3f}"] if start_unix_s is not None else []
    road_map = map_args(map_path)
    regional = ["--regions", "true"] if servers > 1 else []
    workers = ["--cluster_workers", str(cluster_workers)] if cluster_workers > 1 else []
    out = [
        ServiceSpec(
            fusion_name(i, servers),
            FUSION_MODULE,
            [
                "--recording",
                rec,
                "--method",
                method,
                "--pace",
                pace,
                "--connect",
                via(i - 1),
                "--seed",
                str(seed),
                "--interruption_rate",
                str(interruption),
                "--deadline_s",
                str(max(0.05, 0.5 / speed)),
                *road_map,
                *workers,
                *([*regional, "--server_id", sid, "--expected_servers", str(servers)] if sid else []),
            ],
            server_identity(sid) if sid else FUSION,
        )
        for i, sid in enumerate(server_ids(servers) or [""], start=1)
    ]
    for j, vid in enumerate(vehicles):
        out.append(
            ServiceSpec(
                f"agent-{vid}",
                AGENT_MODULE,
                [
                    "--recording",
                    rec,
                    "--vehicle_id",
                    vid,
                    "--method",
                    method,
                    "--pace",
                    pace,
                    "--speed",
                    str(speed),
                    "--connect",
                    via(j + 1),  # agent 1 on another router than server 1: traffic crosses the mesh
                    "--seed",
                    str(seed),
                    *start,
                    *regional,
                ],
                vehicle_identity(vid),
            )
        )
    if api:
        out.append(api_spec(recording, connect, api_port, road_map, servers, truth_dir))
    return out


@dataclass
class FleetProcesses:
    """The running processes by service name; each one's output goes to `log_dir/<name>.log`.

    `security`: each process joins the bus as its spec's identity with these certificates (or
    explicitly insecure); None: the processes inherit this process's environment.
    """

    procs: dict[str, subprocess.Popen[bytes]] = field(default_factory=dict)
    log_dir: Path | None = None
    security: BusSecurity | None = None

    def env_for(self, spec: ServiceSpec) -> dict[str, str]:
        if self.security is None:
            return {}
        if self.security.secure and spec.identity:
            return self.security.as_identity(spec.identity).env()
        return self.security.env()

    def start(self, spec: ServiceSpec, env: dict[str, str] | None = None) -> subprocess.Popen[bytes]:
        out: Any = subprocess.DEVNULL
        if self.log_dir is not None:
            self.log_dir.mkdir(parents=True, exist_ok=True)
            out = (self.log_dir / f"{spec.name}.log").open("ab")
        p = subprocess.Popen(
            [sys.executable, "-m", spec.module, *spec.args],
            stdout=out,
            stderr=out,
            # jemalloc where the machine has it (coplane.allocator): GTSAM's many small
            # allocations cost the fusion server about a quarter more CPU on glibc's malloc
            env={**os.environ, **allocator_env(), **self.env_for(spec), **(env or {})},
        )
        if out is not subprocess.DEVNULL:
            out.close()  # the child has its own descriptor
        self.procs[spec.name] = p
        log.debug("started", extra={"service": spec.name, "pid": p.pid})
        return p

    def stop(self, name: str, timeout: float = 10.0) -> None:
        """SIGTERM (the services then end cleanly: tokens withdrawn, final diagnostics sent),
        SIGKILL after `timeout` seconds."""
        self.stop_many([name], timeout)

    def stop_many(self, names: Sequence[str], timeout: float) -> None:
        """SIGTERM to all of `names` at once, then wait for them together; SIGKILL what is left
        after `timeout` seconds. Every one is reaped (no zombies)."""
        running = [(n, p) for n in names if (p := self.procs.get(n)) is not None and p.poll() is None]
        for _, p in running:
            with contextlib.suppress(ProcessLookupError):
                p.send_signal(signal.SIGTERM)
        deadline = time.monotonic() + timeout
        for name, p in running:
            try:
                p.wait(max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                log.warning("did not stop, killing it", extra={"service": name, "pid": p.pid})
                p.kill()
                p.wait()

    def stop_all(self, timeout: float = STOP_TIMEOUT_S) -> None:
        """Stop every service at once, then the router (so the services' last messages still
        leave); within about `timeout` seconds in all."""
        names = list(self.procs)
        services = [n for n in names if n != "zenoh-router"]
        self.stop_many(services, timeout * 0.75)
        self.stop_many([n for n in names if n not in services], timeout * 0.25)

    def kill_all(self) -> None:
        """SIGKILL every process still running and reap it (the last resort of a stuck stop)."""
        for p in self.procs.values():
            if p.poll() is None:
                with contextlib.suppress(ProcessLookupError):
                    p.kill()
        for p in self.procs.values():
            with contextlib.suppress(subprocess.TimeoutExpired):
                p.wait(1.0)
