"""Helpers for multi-process tests: a short simulated recording and a fleet of real processes.

`running_fleet` is secure by default, as `coplane fleet` is: certificates in a temporary folder,
a TLS router with access control, every process as its own identity, and the test's own sessions
(the collector, watchers) as the read-only `monitor` identity.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TypeVar

from coplane.bus import MONITOR, BusSecurity, use_security
from coplane.bus.certs import init_certs
from coplane.fleet import (
    Collector,
    FleetProcesses,
    fleet_of,
    fleet_services,
    free_port,
    router_spec,
    wait_for_port,
)
from coplane.fleet.launcher import server_ids
from coplane.messages import SolutionMessage
from coplane.runtime import RegionOptions

T = TypeVar("T")


@dataclass
class LiveFleet:
    """A fleet started by `live_fleet`: its processes, the test's collector, where it listens."""

    procs: FleetProcesses
    collector: Collector
    connect: str
    specs: list
    fleet: str
    security: BusSecurity  # the fleet's (insecure, or the certificates folder)


def region_options(args: Sequence[str]) -> RegionOptions:
    """The region settings that `--flag value` pairs (a fleet's `region_args`) give its processes."""
    return RegionOptions.model_validate(
        {k.removeprefix("--"): v for k, v in zip(args[::2], args[1::2], strict=True)}
    )


@contextmanager
def live_fleet(
    recording: Path,
    method: str,
    pace: str = "lockstep",
    speed: float = 1.0,
    log_dir: Path | None = None,
    extra_fusion_args: Sequence[str] = (),
    start_delay_s: float = 5.0,
    secure: bool = True,
    agents: Sequence[str] | None = None,
    map_path: Path | None = None,
    listeners: Sequence[Callable[[SolutionMessage], None]] = (),
    servers: int = 1,
    region_args: Sequence[str] = (),
    agent_args: Mapping[str, Sequence[str]] | None = None,
) -> Iterator[LiveFleet]:
    """Router, fusion server and one agent per vehicle in `agents` (default: every vehicle of the
    recording; certificates are made for all of them) as processes. `secure`: mutual TLS and access
    control (see the module docstring); False: plain TCP. The collector is the read-only monitor and
    knows the recording's vehicles, as `coplane fleet`'s does. `servers` > 1: that many fusion
    servers by region, each server and agent also given `region_args` (e.g. a smaller region).
    `agent_args`: more arguments for the named vehicles' agents."""
    fleet, vehicles = fleet_of(recording)
    port = free_port()
    connect = f"{'tls' if secure else 'tcp'}/127.0.0.1:{port}"
    stack = ExitStack()
    security = BusSecurity(insecure=True)
    if secure:
        certs = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="coplane-certs-")))
        init_certs(certs, vehicles, servers=server_ids(servers))  # each server its own identity
        security = BusSecurity(certs=certs)
        stack.enter_context(use_security(security.as_identity(MONITOR)))
    else:
        stack.enter_context(use_security(security))
    procs = FleetProcesses(log_dir=log_dir, security=security)
    collector = None
    try:
        procs.start(router_spec(port, secure, fleet))
        wait_for_port(port)
        regions = region_options(region_args).region_config() if servers > 1 else None
        collector = Collector(fleet, method, connect, vehicles=vehicles, listeners=listeners, regions=regions)
        start = time.time() + start_delay_s if pace == "realtime" else None
        running = list(agents) if agents is not None else vehicles
        specs = fleet_services(
            recording,
            method,
            pace,
            speed,
            connect,
            running,
            api=False,
            start_unix_s=start,
            map_path=map_path,
            servers=servers,
        )
        for spec in specs:
            if spec.name.startswith("fusion-server"):
                spec.args += list(extra_fusion_args)
            if servers > 1 and spec.name.startswith(("fusion-server", "agent-")):
                spec.args += list(region_args)
            if spec.name.startswith("agent-"):
                spec.args += list((agent_args or {}).get(spec.name.removeprefix("agent-"), ()))
        for spec in specs:
            procs.start(spec)
        yield LiveFleet(procs, collector, connect, specs, fleet, security)
    finally:
        if collector is not None:
            collector.close()
        procs.stop_all()
        stack.close()


@contextmanager
def running_fleet(
    recording: Path,
    method: str,
    pace: str = "lockstep",
    speed: float = 1.0,
    log_dir: Path | None = None,
    extra_fusion_args: Sequence[str] = (),
    start_delay_s: float = 5.0,
    secure: bool = True,
) -> Iterator[tuple[FleetProcesses, Collector, str, list]]:
    """`live_fleet` with every agent; yields (procs, collector, connect, specs)."""
    with live_fleet(recording, method, pace, speed, log_dir, extra_fusion_args, start_delay_s, secure) as lf:
        yield lf.procs, lf.collector, lf.connect, lf.specs


def wait_until(cond: Callable[[], bool], timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if cond():
            return
        time.sleep(0.05)
    raise AssertionError(f"timed out after {timeout} s waiting for {what}")


def wait_settled(
    read: Callable[[], T], ok: Callable[[T], bool], settle_s: float, timeout: float, what: str
) -> T:
    """`read()`'s value once `ok` holds of it and it has stayed the same for `settle_s` seconds.

    For state that several processes move, such as two servers' replicas of the road map: it can
    satisfy `ok` for a moment while a commit or a peer's batch is still on its way, and move on
    (tests/fleet/test_fleet_map.py failed so in CI on 2026-12-03), so a single look is not enough."""
    deadline = time.monotonic() + timeout
    value, since = read(), time.monotonic()
    while time.monotonic() < deadline:
        time.sleep(0.2)
        now = read()
        if now != value:
            value, since = now, time.monotonic()
        elif ok(value) and time.monotonic() - since >= settle_s:
            return value
    raise AssertionError(f"timed out after {timeout} s waiting for {what}; last seen: {value!r}")


def agents_done(procs: FleetProcesses) -> bool:
    return all(p.poll() is not None for n, p in procs.procs.items() if n.startswith("agent-"))


# -- clean shutdown: a process tree, signalled and timed -------------------------------------------


def _children_by_parent() -> dict[int, list[int]]:
    out: dict[int, list[int]] = {}
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                ppid = int((d / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
            out.setdefault(ppid, []).append(int(d.name))
    return out


def descendants(pid: int) -> list[int]:
    """Every process below `pid` right now (from /proc)."""
    kids, out, todo = _children_by_parent(), [], [pid]
    while todo:
        for c in kids.get(todo.pop(), []):
            out.append(c)
            todo.append(c)
    return out


def running(pid: int) -> bool:
    """Alive and not a zombie (a zombie is an exited child nobody has reaped)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return False
    return state != "Z"


def start_serving_fleet(
    recording: Path, work: Path, extra: Sequence[str] = (), timeout: float = 240.0
) -> subprocess.Popen[bytes]:
    """`coplane fleet --serve` in its own process group (as a terminal runs it); returns once it
    says it is serving (the replay is over, the API and the bus still run)."""
    api_port = free_port()
    cmd = [sys.executable, "-m", "coplane.cli", "fleet", str(recording), "--port", "0"]
    cmd += [
        "--api-port",
        str(api_port),
        "--serve",
        "--certs",
        str(work / "certs"),
        "--logs",
        str(work / "logs"),
    ]
    p = subprocess.Popen(
        [*cmd, *extra], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, start_new_session=True
    )
    assert p.stdout is not None
    os.set_blocking(p.stdout.fileno(), False)
    seen = b""
    deadline = time.monotonic() + timeout
    while b"serving:" not in seen:
        if p.poll() is not None or time.monotonic() > deadline:
            p.kill()
            raise AssertionError(
                f"coplane fleet --serve did not start serving:\n{seen.decode(errors='replace')[-3000:]}"
            )
        seen += p.stdout.read() or b""
        time.sleep(0.1)
    return p


@dataclass
class StopTiming:
    """What a stop signal did: the exit code, seconds until the parent exited and until the last
    descendant was gone, and the descendants still running after `timeout`."""

    code: int | None
    parent_s: float
    all_s: float
    left: list[int]
    n_processes: int


def signal_and_time(p: subprocess.Popen[bytes], sig: int, group: bool, timeout: float = 10.0) -> StopTiming:
    """Send `sig` to the process group (Ctrl-C in a terminal) or to the parent alone, and time the stop."""
    tree = descendants(p.pid)
    t0 = time.monotonic()
    if group:
        os.killpg(p.pid, sig)
    else:
        p.send_signal(sig)
    try:
        code: int | None = p.wait(timeout)
    except subprocess.TimeoutExpired:
        code = None
    parent_s = time.monotonic() - t0
    while any(running(c) for c in tree) and time.monotonic() - t0 < timeout:
        time.sleep(0.02)
    all_s = time.monotonic() - t0
    left = [c for c in tree if running(c)]
    for c in left:  # never leave a stray process behind a failed test
        with contextlib.suppress(ProcessLookupError):
            os.kill(c, signal.SIGKILL)
    if code is None:
        p.kill()
        p.wait()
    return StopTiming(code, parent_s, all_s, left, len(tree))
