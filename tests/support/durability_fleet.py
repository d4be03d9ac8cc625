"""kill -9 of a fleet service mid-run, then a restart: what was lost (tests and bench/reliability_durability.py).

A fleet of real processes (router, fusion server, agents, optionally the API) replays a recording;
the launcher's `Collector` streams every published solution to its own log. Once `kill_after`
solutions were published, the chosen service gets SIGKILL and is started again at once with the
same arguments. At the end the fusion server is stopped cleanly and the three logs are compared:

- published but not on disk: solutions the collector received that are not in the fusion log;
- missed epochs: epochs of the replay with no solution in the fusion log;
- API: its tracks just before the kill against its tracks after the restart (same epochs), and
  the solutions it never took (published while it was down).
"""

from __future__ import annotations

import json
import signal
import time
import urllib.request
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from coplane.fleet import (
    Collector,
    FleetProcesses,
    fleet_of,
    fleet_services,
    free_port,
    router_spec,
    wait_for_port,
)
from coplane.fleet.launcher import ServiceSpec
from coplane.recording.reader import open_recording
from coplane.replay import vehicle_schedule
from coplane.store import SolutionLog


@dataclass
class KillRun:
    """What one kill-and-restart run measured."""

    target: str  # what was killed: "fusion-server", "api", both joined by "+", or "" (none)
    pace: str
    speed: float
    n_epochs: int  # epochs in the replay
    published: int = 0  # solutions the collector received
    logged: int = 0  # solutions in the fusion log
    published_not_logged: int = 0
    duplicate_epochs: int = 0  # epochs logged more than once
    missed_epochs: int = 0  # replay epochs with no logged solution
    down_s: float = 0.0  # from the kill until the restarted service was back
    resumed: bool = False  # the restarted fusion server resumed from its log
    api_tracks_equal: bool | None = None
    api_points_before: int = 0
    api_missing_after: int = 0  # logged solutions the API never took (it was down)
    notes: list[str] = field(default_factory=list)


def _get(url: str, timeout: float = 5.0) -> Any:
    with urllib.request.urlopen(url, timeout=timeout) as r:
        return json.loads(r.read())


def _api_ready(base: str) -> bool:
    try:
        _get(f"{base}/healthz", 1.0)
        return True
    except Exception:
        return False


def _tracks(base: str, vehicles: list[str]) -> dict[str, list[dict[str, Any]]]:
    return {v: _get(f"{base}/vehicles/{v}/track")["points"] for v in vehicles}


def _wait(cond: Any, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if cond():
            return True
        time.sleep(0.05)
    return False


def _kill_restart(
    procs: FleetProcesses, spec: ServiceSpec, col: Collector, base: str, vehicles: list[str], out: KillRun
) -> float:
    """SIGKILL one service and start it again; returns how long it was gone."""
    api = spec.name == "api"
    before = _tracks(base, vehicles) if api else {}
    p = procs.procs[spec.name]
    p.send_signal(signal.SIGKILL)
    t_kill = time.monotonic()
    p.wait()
    procs.start(spec)
    if api:
        _wait(lambda: _api_ready(base), 60)
        down = time.monotonic() - t_kill
        after = _tracks(base, vehicles)
        out.api_points_before = sum(len(v) for v in before.values())
        out.api_tracks_equal = all(after[v][: len(before[v])] == before[v] for v in vehicles)
        return down
    n0 = col.epochs
    _wait(lambda: col.epochs > n0, 60)
    return time.monotonic() - t_kill


def kill_and_restart(
    recording: Path,
    work: Path,
    targets: Sequence[str],
    *,
    pace: str = "realtime",
    speed: float = 1.0,
    kill_after: int = 10,
    kill_gap: int = 10,
    start_delay_s: float = 10.0,
    method: str = "pc",
    timeout_s: float = 300.0,
) -> KillRun:
    """Run the fleet; SIGKILL each of `targets` in turn (after `kill_after`, then every `kill_gap`
    published solutions) and restart it at once."""
    rec = open_recording(recording)
    fleet, vehicles = fleet_of(recording)
    dt = rec.manifest.interval_s
    epochs = {t for v in vehicles for t, _ in vehicle_schedule(rec.vehicle_epochs(v), dt)}
    out = KillRun("+".join(targets), pace, speed, len(epochs))
    port, api_port = free_port(), free_port()
    connect = f"tcp/127.0.0.1:{port}"
    base = f"http://127.0.0.1:{api_port}"
    fusion_db, api_db = work / "fusion.sqlite", work / "api.sqlite"
    procs = FleetProcesses(log_dir=work / "logs")
    api = "api" in targets
    try:
        procs.start(router_spec(port))
        wait_for_port(port)
        with Collector(fleet, method, connect, out=work / "collector") as col:
            start = time.time() + start_delay_s if pace == "realtime" else None
            specs = fleet_services(
                recording,
                method,
                pace,
                speed,
                connect,
                vehicles,
                api=api,
                api_port=api_port,
                start_unix_s=start,
            )
            by_name = {s.name: s for s in specs}
            by_name["fusion-server"].args += ["--db", str(fusion_db)]
            if api:
                by_name["api"].args += ["--db", str(api_db)]
            for s in specs:
                procs.start(s)
            agents = [n for n in procs.procs if n.startswith("agent-")]
            for i, name in enumerate(targets):
                if not _wait(lambda i=i: col.epochs >= kill_after + i * kill_gap, timeout_s):
                    out.notes.append(f"{name}: never reached the kill point")
                out.down_s = max(out.down_s, _kill_restart(procs, by_name[name], col, base, vehicles, out))
            _wait(lambda: all(procs.procs[a].poll() is not None for a in agents), timeout_s)
            time.sleep(1.0 + 1.0 / speed)  # the last epochs' deadline
            procs.stop("fusion-server")
            time.sleep(0.5)
            if api:
                final_api = _tracks(base, vehicles)
            with col.lock:
                out.published = col.epochs
        procs.stop_all()
        with SolutionLog(fusion_db, writer=False) as lg:
            logged = lg.solutions()
        with SolutionLog(work / "collector" / "solutions.sqlite", writer=False) as lg:
            received = lg.solutions()
        out.logged = len(logged)
        on_disk = {s.model_dump_json() for s in logged}
        out.published_not_logged = sum(1 for s in received if s.model_dump_json() not in on_disk)
        keys = [(s.epoch.week, s.epoch.tow) for s in logged]
        out.duplicate_epochs = len(keys) - len(set(keys))
        out.missed_epochs = len({(t.week, t.tow) for t in epochs} - set(keys))
        log_text = (work / "logs" / "fusion-server.log").read_text(errors="replace")
        out.resumed = "resumed from the solution log" in log_text
        if api:
            api_epochs = {(p["week"], p["tow"]) for pts in final_api.values() for p in pts}
            out.api_missing_after = len(set(keys) - api_epochs)
        return out
    finally:
        procs.stop_all()
