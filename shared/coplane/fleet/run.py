"""`run_fleet`: replay a recording as a fleet of processes on this machine and collect the result.

Starts a Zenoh router, the fusion server, one vehicle agent per vehicle (and the API when asked),
listens to the solutions itself (`Collector`) and stops everything cleanly. The caller renders the
`FleetResult`; progress and "keep serving" are the caller's callbacks, so this module prints nothing.

Secure by default: certificates for the recording's identities are made (or reused) in
`FleetOptions.certs` (default `default_certs_dir()`), the router listens on TLS with mutual
authentication and access control, and every process connects as its own identity (the collector
as `monitor`). `insecure=True` runs plain TCP without access control, for debugging only.

`stop` (an Event, set by the caller's signal handler) ends a replay early or ends serving; every
process is then stopped together (coplane.fleet.launcher.FleetProcesses.stop_all).
"""

from __future__ import annotations

import logging
import math
import os
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import get_args

from coplane.bus.certs import init_certs
from coplane.bus.security import MONITOR, BusSecurity, use_security, warn_insecure
from coplane.errors import ConfigError
from coplane.evaluate.metrics import AccuracyStats
from coplane.evaluate.report import run_stats, write_exclusions, write_solutions
from coplane.evaluate.runner import MethodRun
from coplane.evaluate.solution_files import check_formats, write_solution_formats
from coplane.evaluate.truth import Truth, TruthChoice, apply_truth, missing_truth_note, save_truth
from coplane.fleet.collector import Collector
from coplane.fleet.launcher import (
    FleetProcesses,
    api_spec,
    fleet_of,
    fleet_services,
    free_port,
    map_args,
    router_spec,
    server_ids,
    wait_for_port,
)
from coplane.live.nmea_out import NmeaServer
from coplane.live.urls import MAX_PORT
from coplane.messages import DiagnosticsMessage
from coplane.methods import get_method
from coplane.recording.health import InputHealth, input_health
from coplane.recording.reader import open_recording
from coplane.regions import RegionConfig
from coplane.replay import vehicle_schedule
from coplane.store import map_path
from coplane.typing import Pace

log = logging.getLogger("coplane.fleet")

PACES = get_args(Pace)
REALTIME_START_DELAY_S = 5.0  # the shared realtime origin: once every process is up
POLL_S = 0.2


@dataclass(frozen=True)
class FleetOptions:
    """What `coplane fleet` takes. `port` 0: any free port; `interruption` is a rate in [0, 1]."""

    recording: Path
    method: str = "pc"
    pace: str = "lockstep"
    speed: float = 1.0
    api: bool = True
    api_port: int = 8000
    port: int = 7447
    out: Path | None = None
    logs: Path | None = None
    seed: int = 0
    interruption: float = 0.0
    insecure: bool = False
    certs: Path | None = None  # the certificates folder; default: default_certs_dir()
    map: Path | None = None  # road-surface map the fusion server extends and shares; None: the
    # fleet's map in the state directory (store.map_path "auto"), Path("none"): no map
    nmea_port: int | None = None  # NMEA 0183 GGA + RMC per vehicle on this port and the next ones
    servers: int = 1  # fusion servers sharing the fleet by region (docs/scale.md)
    routers: int = 1  # Zenoh routers in a mesh; servers and agents take them in turn
    cluster_workers: int = 1  # processes per fusion server solving its clusters (same estimates)
    # "rtk": RTKLIB's RTK reference; a TruthChoice's files: other tools' references (`evaluate.truth`)
    # for the accuracy table and the API alike
    truth: Truth | TruthChoice = "recording"
    # extra solution files beside the CSVs in `out` (`evaluate.solution_files.SOLUTION_FORMATS`)
    formats: frozenset[str] = frozenset()
    # how long the replay waits for the API to listen: it loads its solutions log first (up to
    # ~30 s at the default size); after that the replay starts anyway, with a warning
    api_start_timeout_s: float = 60.0

    def __post_init__(self) -> None:
        """Values no process could use are named here, before any process starts (a zero speed
        divided by zero, a port above 65535 overflowed a socket call, a rate of 150 % ran); the
        pace too, which the command line already limits but code calling run_fleet does not."""
        if not (math.isfinite(self.speed) and self.speed > 0):
            raise ConfigError(f"--speed must be a finite factor > 0, got {self.speed}")
        if not 0.0 <= self.interruption <= 1.0:  # NaN fails too
            raise ConfigError(f"--interruption must be within 0..100 %, got {self.interruption * 100:g}")
        for option, port, lowest in (("--port", self.port, 0), ("--api-port", self.api_port, 1)):
            if not lowest <= port <= MAX_PORT:
                raise ConfigError(f"{option} must be within {lowest}..{MAX_PORT}, got {port}")
        if self.pace not in PACES:
            raise ConfigError(f"--pace must be lockstep or realtime, got {self.pace!r}")
        check_formats(self.formats)
        if self.formats and self.out is None:
            raise ConfigError("--format writes its files into --out: give --out DIR")


MAX_FLEET_SERVERS = 16  # fusion server processes `coplane fleet` starts on one machine
MAX_FLEET_ROUTERS = 4  # Zenoh routers it meshes


def default_certs_dir() -> Path:
    """$COPLANE_BUS_CERTS if set, else $XDG_STATE_HOME/coplane/certs (~/.local/state/coplane/certs)."""
    if env := os.environ.get("COPLANE_BUS_CERTS"):
        return Path(env)
    state = os.environ.get("XDG_STATE_HOME") or str(Path.home() / ".local" / "state")
    return Path(state) / "coplane" / "certs"


def fleet_security(options: FleetOptions, vehicles: list[str]) -> BusSecurity:
    """The fleet's bus security: certificates made or completed for these vehicles, or insecure."""
    if options.insecure:
        warn_insecure("coplane fleet --insecure")
        return BusSecurity(insecure=True)
    folder = (options.certs or default_certs_dir()).resolve()
    made = init_certs(folder, vehicles, servers=server_ids(options.servers))
    if made.created:
        log.info("certificates made", extra={"folder": str(folder), "identities": ",".join(made.created)})
    return BusSecurity(certs=folder, insecure=False)


@dataclass
class FleetResult:
    """What a fleet replay produced, as seen on the bus by the launcher."""

    recording_name: str
    method: str
    vehicles: list[str]
    truth_vehicles: list[str]  # the vehicles with truth, in manifest order
    run: MethodRun
    stats: dict[str, AccuracyStats]  # per vehicle with truth
    diagnostics: DiagnosticsMessage | None  # the fusion server's last
    failed_agents: dict[str, int]  # agent service -> exit code, for those that failed
    n_epochs: int
    solutions_dir: Path | None = None  # where --out wrote the solution CSVs
    api_url: str | None = None
    secure: bool = True
    interrupted: bool = False  # stopped by `stop` before the replay ended
    input_problems: dict[str, int] = field(default_factory=dict)  # what the recording's reader found
    input_health: InputHealth | None = None  # records kept vs problems (`--strict`)
    nmea_ports: dict[str, int] = field(default_factory=dict)  # vehicle -> NMEA TCP port (--nmea-port)
    truth_note: str = ""  # what the truth was (`--truth rtk|ID=FILE`), or which vehicles have none


Progress = Callable[[int, int], None]  # (epochs solved so far, epochs in the replay)


def run_fleet(
    options: FleetOptions,
    progress: Progress | None = None,
    serve: Callable[[FleetResult], None] | None = None,
    stop: threading.Event | None = None,
    procs: FleetProcesses | None = None,
    on_nmea: Callable[[dict[str, int]], None] | None = None,
) -> FleetResult:
    """Run the replay to its end (or until `stop` is set) and return what the launcher collected.

    `on_nmea`: told the NMEA ports (vehicle -> port) once they listen, before any process starts.

    `serve`: called with the result while the fusion server, API and router still run (they are
    stopped when it returns; `coplane fleet --serve` waits there for `stop`). Without it the
    fusion server is stopped first, so its final diagnostics are in the result. `procs`: the
    process table to fill (the caller's signal watchdog kills what it holds).
    """
    o = options
    method = get_method(o.method)
    stop = stop or threading.Event()
    path = o.recording.resolve()
    rec = open_recording(path)
    # a recording without a base or RTKLIB, or a reference file that cannot be read, is refused
    # here, before any process starts
    truth_note = apply_truth(rec, o.truth)
    fleet_name, vehicles = fleet_of(path)
    if not 1 <= o.servers <= MAX_FLEET_SERVERS:
        raise ConfigError(f"--servers must be in 1..{MAX_FLEET_SERVERS}, got {o.servers}")
    if not 1 <= o.routers <= MAX_FLEET_ROUTERS:
        raise ConfigError(f"--routers must be in 1..{MAX_FLEET_ROUTERS}, got {o.routers}")
    if o.cluster_workers < 1:
        raise ConfigError(f"--cluster-workers must be at least 1, got {o.cluster_workers}")
    # with --servers > 1 each server keeps its own replica beside this file (docs/scale.md)
    road_map = map_path(o.map if o.map is not None else "auto", fleet_name)
    if method.plane_map and road_map is None:
        raise ConfigError(
            f"method {o.method!r} takes its planes from a road-surface map: drop --map none, or give"
            " one (--map MAP; `coplane map build` makes it)"
        )
    interval = rec.manifest.interval_s
    n_epochs = len({t for v in vehicles for t, _ in vehicle_schedule(rec.vehicle_epochs(v), interval)})
    security = fleet_security(o, vehicles)
    port = o.port or free_port()
    scheme = "tls" if security.secure else "tcp"
    connect = f"{scheme}/127.0.0.1:{port}"
    procs = procs if procs is not None else FleetProcesses()
    nmea: NmeaServer | None = None
    procs.log_dir, procs.security = o.logs, security
    # the API measures against the RTK reference made above, not a second one of its own
    truth_files = tempfile.TemporaryDirectory(prefix="coplane-truth-") if truth_note and o.api else None
    log.info("fleet starting", extra={"fleet": fleet_name, "vehicles": len(vehicles), "router": connect})
    try:
        procs.start(router_spec(port, security.secure, fleet_name))
        wait_for_port(port)
        mesh = [connect]
        for k in range(2, o.routers + 1):  # each further router joins the first: a star of links
            extra = free_port()
            procs.start(router_spec(extra, security.secure, fleet_name, mesh=[port], index=k))
            wait_for_port(extra)
            mesh.append(f"{scheme}/127.0.0.1:{extra}")
        if o.nmea_port is not None:
            nmea = NmeaServer(vehicles, o.nmea_port)
            log.info("NMEA output", extra={"ports": ", ".join(f"{v}:{p}" for v, p in nmea.ports.items())})
            if on_nmea is not None:
                on_nmea(nmea.ports)
        with use_security(security.as_identity(MONITOR) if security.secure else security):
            collector = Collector(
                fleet_name,
                o.method,
                connect,
                out=o.out,
                vehicles=vehicles,
                listeners=[nmea.publish] if nmea is not None else [],
                regions=RegionConfig() if o.servers > 1 else None,  # the launcher's: the defaults
            )
        with collector:
            truth_dir = save_truth(rec, Path(truth_files.name)) if truth_files is not None else None

            map_file = road_map.resolve() if road_map is not None else None
            if o.api:  # listening means subscribed (uvicorn binds after the lifespan): it sees every epoch
                api = procs.start(
                    api_spec(path, connect, o.api_port, map_args(map_file), o.servers, truth_dir)
                )
                try:
                    wait_for_port(o.api_port, o.api_start_timeout_s, api)
                except TimeoutError:  # a long solutions log to load: the replay does not wait for it
                    log.warning(
                        "the API is not listening yet; its accuracy may miss the first epochs",
                        extra={"waited_s": o.api_start_timeout_s},
                    )
            # the realtime origin can only be fixed once the API is up
            start = time.time() + REALTIME_START_DELAY_S if o.pace == "realtime" else None
            for spec in fleet_services(
                path,
                o.method,
                o.pace,
                o.speed,
                connect,
                vehicles,
                False,  # the API runs already
                o.api_port,
                o.seed,
                o.interruption,
                start,
                map_path=map_file,
                servers=o.servers,
                routers=mesh,
                cluster_workers=o.cluster_workers,
            ):
                procs.start(spec)
            agents = [n for n in procs.procs if n.startswith("agent-")]
            while any(procs.procs[a].poll() is None for a in agents) and not stop.wait(POLL_S):
                if progress is not None:
                    progress(collector.epochs, n_epochs)
            if not stop.is_set():
                stop.wait(0.5)  # the last solution is on its way
            if progress is not None:
                progress(collector.epochs, n_epochs)
            if serve is None and not stop.is_set():
                # they publish their final diagnostics on the way out
                procs.stop_many([n for n in procs.procs if n.startswith("fusion-server")], 10.0)
                stop.wait(0.3)
            failed = {a: rc for a in agents if (rc := procs.procs[a].returncode)}
            if failed and not stop.is_set():
                log.error(
                    "agents failed", extra={"agents": ",".join(f"{a}={rc}" for a, rc in failed.items())}
                )
            result = FleetResult(
                recording_name=rec.manifest.name,
                method=o.method,
                vehicles=vehicles,
                truth_vehicles=[v for v in vehicles if rec.truth_at(v)],
                run=collector.run,
                stats=run_stats(collector.run, rec),
                diagnostics=collector.diag,
                failed_agents={} if stop.is_set() else failed,
                n_epochs=n_epochs,
                api_url=f"http://127.0.0.1:{o.api_port}" if o.api else None,
                secure=security.secure,
                interrupted=stop.is_set(),
                input_problems=dict(rec.problems.counts),
                input_health=input_health(rec),
                nmea_ports=dict(nmea.ports) if nmea is not None else {},
                truth_note="; ".join(n for n in (truth_note, missing_truth_note(rec)) if n),
            )
            if o.out is not None:
                write_solutions(collector.run, o.out)
                write_exclusions([collector.run], o.out)
                write_solution_formats([collector.run], rec, o.out, o.formats)
                result.solutions_dir = o.out / "solutions" / collector.run.label
            if serve is not None and not stop.is_set():
                serve(result)
            return result
    finally:
        procs.stop_all()
        if nmea is not None:
            nmea.close()
        if truth_files is not None:
            truth_files.cleanup()
