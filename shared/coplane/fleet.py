"""`coplane fleet`: run a whole fleet replay as separate processes on this machine.

Starts a Zenoh router, the fusion server, one vehicle agent per vehicle (and the API when asked),
listens to the solutions itself for progress and the accuracy table, and stops everything cleanly.
docker-compose.yml starts the same services (tests/test_compose.py keeps the two in sync).
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import zenoh

from coplane.bus import BadMessage, KeySpace, decode, payload_bytes, session_config
from coplane.evaluate.runner import MethodRun, record_solution
from coplane.messages import DiagnosticsMessage, SolutionMessage
from coplane.recording.manifest import load_manifest
from coplane.replay import fleet_id


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@dataclass
class ServiceSpec:
    """One process of the fleet: the same list drives the launcher and is checked against compose."""

    name: str  # compose service name
    module: str  # python -m <module>
    args: list[str] = field(default_factory=list)


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
) -> list[ServiceSpec]:
    """The fleet's processes. `start_unix_s`: realtime agents' shared wall-clock origin."""
    rec = str(recording)
    start = ["--start_unix_s", f"{start_unix_s:.3f}"] if start_unix_s is not None else []
    out = [
        ServiceSpec(
            "fusion-server",
            "coplane.fusion",
            [
                "--recording",
                rec,
                "--method",
                method,
                "--pace",
                pace,
                "--connect",
                f'["{connect}"]',
                "--seed",
                str(seed),
                "--interruption_rate",
                str(interruption),
                "--deadline_s",
                str(max(0.05, 0.5 / speed)),
            ],
        )
    ]
    for vid in vehicles:
        out.append(
            ServiceSpec(
                f"agent-{vid}",
                "coplane.agent",
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
                    f'["{connect}"]',
                    "--seed",
                    str(seed),
                    *start,
                ],
            )
        )
    if api:
        out.append(
            ServiceSpec(
                "api",
                "coplane.api",
                ["--recording", rec, "--connect", f'["{connect}"]', "--port", str(api_port)],
            )
        )
    return out


class Collector:
    """Subscribes to solutions and diagnostics; keeps what the accuracy table and --out need."""

    def __init__(self, fleet: str, method: str, connect: str) -> None:
        self.keys = KeySpace(fleet)
        self.run = MethodRun(method, 0.0)
        self.lock = threading.Lock()
        self.epochs = 0
        self.diag: DiagnosticsMessage | None = None
        self.bad = 0
        self.session = zenoh.open(session_config("client", [connect]))
        self.session.declare_subscriber(self.keys.solution, self._on_solution)
        self.session.declare_subscriber(self.keys.diagnostics, self._on_diag)

    def _on_solution(self, sample: Any) -> None:
        try:
            sol = decode(SolutionMessage, payload_bytes(sample))
        except BadMessage:
            self.bad += 1
            return
        with self.lock:
            record_solution(self.run, sol, {})
            self.epochs += 1

    def _on_diag(self, sample: Any) -> None:
        try:
            self.diag = decode(DiagnosticsMessage, payload_bytes(sample))
        except BadMessage:
            self.bad += 1

    def close(self) -> None:
        self.session.close()


@dataclass
class FleetProcesses:
    procs: dict[str, subprocess.Popen[bytes]] = field(default_factory=dict)
    log_dir: Path | None = None

    def start(self, spec: ServiceSpec, env: dict[str, str] | None = None) -> subprocess.Popen[bytes]:
        out: Any = subprocess.DEVNULL
        if self.log_dir is not None:
            self.log_dir.mkdir(parents=True, exist_ok=True)
            out = (self.log_dir / f"{spec.name}.log").open("ab")
        p = subprocess.Popen(
            [sys.executable, "-m", spec.module, *spec.args],
            stdout=out,
            stderr=out,
            env={**os.environ, **(env or {})},
        )
        self.procs[spec.name] = p
        return p

    def stop(self, name: str, timeout: float = 10.0) -> None:
        p = self.procs.get(name)
        if p is None or p.poll() is not None:
            return
        p.send_signal(signal.SIGTERM)
        try:
            p.wait(timeout)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()

    def stop_all(self) -> None:
        for name in reversed(list(self.procs)):
            self.stop(name)


def wait_for_port(port: int, timeout: float = 15.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return
        time.sleep(0.05)
    raise TimeoutError(f"nothing listens on 127.0.0.1:{port} after {timeout} s")


def router_spec(port: int) -> ServiceSpec:
    return ServiceSpec("zenoh-router", "coplane.router", ["--listen", f"tcp/127.0.0.1:{port}"])


def fleet_of(recording: Path) -> tuple[str, list[str]]:
    man = load_manifest(recording)
    return fleet_id(man.name), [v.id for v in man.vehicles]


# -- docker-compose: generated from the same service list the launcher starts -------------------
COMPOSE_RECORDING = "/app/shared/coplane/data/recordings/default"  # the bundled recording in the image
COMPOSE_ROUTER = "tcp/zenoh-router:7447"
ZENOH_IMAGE = "eclipse/zenoh:1.10.2"


def compose_document(
    vehicles: Sequence[str], method: str = "pc", pace: str = "realtime", speed: float = 1.0
) -> dict[str, Any]:
    """The docker-compose.yml content for a fleet replay of the bundled recording.

    Service names, modules and arguments come from `fleet_services`, so the compose file and
    `coplane fleet` start the same processes (tests/test_compose.py checks the committed file).
    """
    services: dict[str, Any] = {
        "zenoh-router": {
            "image": ZENOH_IMAGE,
            "command": ["-c", "/etc/zenoh/router.json5"],
            "volumes": ["./deploy/zenoh/router.json5:/etc/zenoh/router.json5:ro"],
            "ports": ["7447:7447"],
            "restart": "unless-stopped",
        }
    }
    for spec in fleet_services(
        Path(COMPOSE_RECORDING), method, pace, speed, COMPOSE_ROUTER, vehicles, api=True
    ):
        svc: dict[str, Any] = {
            "build": ".",
            "image": "coplane:latest",
            "command": ["python", "-m", spec.module, *spec.args],
            "depends_on": ["zenoh-router"],
            "restart": "on-failure",
            "healthcheck": {
                "test": [
                    "CMD",
                    "python",
                    "-c",
                    "import socket; socket.create_connection(('zenoh-router', 7447), 2)",
                ],
                "interval": "10s",
                "timeout": "3s",
                "retries": 3,
            },
        }
        if spec.name == "api":
            svc["ports"] = ["8000:8000"]
            svc["command"] = [*svc["command"], "--host", "0.0.0.0"]
            svc["healthcheck"] = {
                "test": [
                    "CMD",
                    "python",
                    "-c",
                    "import urllib.request; urllib.request.urlopen('http://127.0.0.1:8000/healthz', timeout=2)",
                ],
                "interval": "10s",
                "timeout": "3s",
                "retries": 3,
            }
        services[spec.name] = svc
    return {"services": services}
