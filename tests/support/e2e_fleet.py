"""Helpers for multi-process tests: a short simulated recording and a fleet of real processes."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

from coplane.fleet import (
    Collector,
    FleetProcesses,
    fleet_of,
    fleet_services,
    free_port,
    router_spec,
    wait_for_port,
)


@contextmanager
def running_fleet(
    recording: Path,
    method: str,
    pace: str = "lockstep",
    speed: float = 1.0,
    log_dir: Path | None = None,
    extra_fusion_args: Sequence[str] = (),
    start_delay_s: float = 5.0,
) -> Iterator[tuple[FleetProcesses, Collector, str, list]]:
    """Router, fusion server and one agent per vehicle as processes; yields (procs, collector, connect, specs)."""
    fleet, vehicles = fleet_of(recording)
    port = free_port()
    connect = f"tcp/127.0.0.1:{port}"
    procs = FleetProcesses(log_dir=log_dir)
    collector = None
    try:
        procs.start(router_spec(port))
        wait_for_port(port)
        collector = Collector(fleet, method, connect)
        start = time.time() + start_delay_s if pace == "realtime" else None
        specs = fleet_services(
            recording, method, pace, speed, connect, vehicles, api=False, start_unix_s=start
        )
        specs[0].args += list(extra_fusion_args)
        for spec in specs:
            procs.start(spec)
        yield procs, collector, connect, specs
    finally:
        if collector is not None:
            collector.close()
        procs.stop_all()


def wait_until(cond: Callable[[], bool], timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if cond():
            return
        time.sleep(0.05)
    raise AssertionError(f"timed out after {timeout} s waiting for {what}")


def agents_done(procs: FleetProcesses) -> bool:
    return all(p.poll() is not None for n, p in procs.procs.items() if n.startswith("agent-"))
