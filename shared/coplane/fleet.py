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
) -> list[ServiceSpec]:
    rec = str(recording)
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
