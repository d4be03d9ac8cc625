"""`coplane fleet`: replay a recording as a fleet of processes over Zenoh (coplane.fleet.run_fleet).

Ctrl-C (SIGINT, to the whole process group) or SIGTERM (to this process alone) stops every
process of the fleet, together, and exits 130 or 143 within 5 s; if a stop hangs, the watchdog
kills the children and exits anyway (coplane.runtime.stop_event).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from coplane.cli.options import FORMAT_HELP, progress_bars, recording_or_default, solution_formats
from coplane.cli.render import STRICT_HELP, check_input, console, err_console, print_accuracy, print_problems
from coplane.typing import Pace

if TYPE_CHECKING:
    from coplane.fleet import FleetResult
    from coplane.messages import DiagnosticsMessage


def fleet(
    recording: Annotated[
        Path | None, typer.Argument(help="Fleet recording; default: the bundled one.")
    ] = None,
    method: Annotated[str, typer.Option(help="Estimator method.")] = "pc",
    pace: Annotated[Pace, typer.Option(help="lockstep (deterministic) or realtime.")] = "lockstep",
    speed: Annotated[float, typer.Option(help="Realtime speed factor.")] = 1.0,
    serve: Annotated[bool, typer.Option(help="Keep the API (and the bus) running after the replay.")] = False,
    api: Annotated[bool, typer.Option(help="Start the HTTP API.")] = True,
    api_port: Annotated[int, typer.Option(help="API port.")] = 8000,
    port: Annotated[int, typer.Option(help="Zenoh router port (0: any free port).")] = 7447,
    out: Annotated[Path | None, typer.Option(help="Write solutions/<method>/<vehicle>.csv here.")] = None,
    fmt: Annotated[str, typer.Option("--format", help=FORMAT_HELP + " Needs --out.")] = "",
    logs: Annotated[Path | None, typer.Option(help="Folder for each process's JSON log.")] = None,
    seed: Annotated[int, typer.Option(help="Seed (planes, interruption).")] = 0,
    interruption: Annotated[float, typer.Option(help="Ranging interruption rate in %.")] = 0.0,
    insecure: Annotated[
        bool, typer.Option(help="Plain TCP, no certificates, no access control (debugging only).")
    ] = False,
    certs: Annotated[
        Path | None,
        typer.Option(
            help="Certificates folder, made or completed as needed; default: ~/.local/state/coplane/certs."
        ),
    ] = None,
    strict: Annotated[bool, typer.Option(help=STRICT_HELP)] = False,
    map_file: Annotated[
        Path | None,
        typer.Option(
            "--map",
            help="Road-surface map (SQLite) the fusion server extends with this run's solutions and shares with "
            "the agents on the bus (pc-map, pc-self-map); default: the fleet's map in the state directory; "
            "'none': no map.",
        ),
    ] = None,
    servers: Annotated[
        int,
        typer.Option(
            "--servers",
            min=1,
            max=16,
            help="Fusion servers sharing the fleet by region (docs/scale.md); 1: one server for all.",
        ),
    ] = 1,
    routers: Annotated[
        int,
        typer.Option(
            "--routers",
            min=1,
            max=4,
            help="Zenoh routers in a mesh (the others join the first); servers and agents take them in turn.",
        ),
    ] = 1,
    cluster_workers: Annotated[
        int,
        typer.Option(
            "--cluster-workers",
            min=1,
            max=64,
            help="Processes per fusion server that solve its clusters (docs/scale.md); the estimates are the "
            "same for any number.",
        ),
    ] = 1,
    nmea_port: Annotated[
        int | None,
        typer.Option(
            "--nmea-port",
            help="NMEA 0183 GGA + GST + RMC over TCP on 127.0.0.1: the first vehicle on this port, the next ones "
            "on the following ports (0: any free ports; printed at start).",
        ),
    ] = None,
    truth: Annotated[
        list[str] | None,
        typer.Option(
            help="What the accuracy table and the API measure against: 'recording' (its truth files, the"
            " default), 'rtk' (RTKLIB's carrier-phase RTK to the recording's base, where it holds), and/or"
            " ID=FILE (repeatable): vehicle ID's reference trajectory from another tool (RTKLIB .pos,"
            " Inertial Explorer text export, truth CSV), or ID=x,y,z / ID=lat,lon,h: a static receiver's"
            " surveyed point.",
        ),
    ] = None,
) -> None:
    """Replay a recording as a fleet of processes over Zenoh and print the accuracy table.

    The bus is secure by default: mutual TLS, one certificate per process, router access control.
    """
    from tqdm import tqdm

    from coplane.evaluate.truth import parse_truth_choice
    from coplane.fleet import FleetOptions, FleetProcesses, run_fleet
    from coplane.runtime import STOP_GRACE_S, exit_code, stop_signals

    procs = FleetProcesses()
    if insecure:
        err_console.print(
            "[bold red]WARNING: --insecure: plain TCP, no authentication, no access control[/bold red]"
        )

    options = FleetOptions(
        recording=recording_or_default(recording),
        method=method,
        pace=pace,
        speed=speed,
        api=api,
        api_port=api_port,
        port=port,
        out=out,
        logs=logs,
        seed=seed,
        interruption=interruption / 100,
        insecure=insecure,
        certs=certs,
        map=map_file,
        nmea_port=nmea_port,
        servers=servers,
        routers=routers,
        cluster_workers=cluster_workers,
        truth=parse_truth_choice(truth),
        formats=solution_formats(fmt),
    )
    bars: list[Any] = []  # the progress bar, once the replay's length is known

    def show_nmea(ports: dict[str, int]) -> None:
        err_console.print(
            "NMEA 0183 (GGA + GST + RMC): " + ", ".join(f"{v} tcp://127.0.0.1:{p}" for v, p in ports.items())
        )

    def progress(done: int, total: int) -> None:
        if not bars:
            bars.append(
                tqdm(total=total, desc=f"fleet {method} ({pace})", unit="epoch", disable=not progress_bars())
            )
        bars[0].update(done - bars[0].n)

    def close_bar() -> None:
        while bars:
            bars.pop().close()

    def keep_serving(result: FleetResult) -> None:
        close_bar()
        _render(result)
        console.print(f"serving: API on {result.api_url} (Ctrl-C to stop)")
        stop.wait()

    # the children get STOP_GRACE_S; this process needs a little more to reap them
    with stop_signals(grace_s=STOP_GRACE_S + 1.5, on_deadline=procs.kill_all) as stop:
        try:
            result = run_fleet(
                options, progress, keep_serving if serve else None, stop, procs, on_nmea=show_nmea
            )
        finally:
            close_bar()
    if not serve or result.interrupted:
        _render(result)
    if stop.is_set():
        raise typer.Exit(exit_code())
    _check_input(result, strict)


def _check_input(result: FleetResult, strict: bool) -> None:
    """The recording's input-problem count and warnings, as `coplane eval` prints them."""
    from coplane.recording.health import health_warnings

    print_problems(result.input_problems)
    if result.input_health is not None:
        fixes = sum(len(p) for p in result.run.positions.values())
        check_input(health_warnings(result.input_health, fixes), strict)


def _render(result: FleetResult) -> None:
    if result.interrupted:
        err_console.print("interrupted: the table covers the epochs solved so far")
    if result.truth_note:
        err_console.print(result.truth_note)
    if result.failed_agents:
        err_console.print(f"[red]agents failed:[/red] {result.failed_agents} (see --logs)")
    print_accuracy(
        f"{result.recording_name} (fleet over Zenoh)", {result.method: result.stats}, result.truth_vehicles
    )
    if result.diagnostics is not None:
        console.print(message_counts(result.diagnostics))
    if result.solutions_dir is not None:
        console.print(f"wrote {result.solutions_dir}/")


def message_counts(diagnostics: DiagnosticsMessage) -> str:
    """'messages: u1: used 600/601, late 0, rejected 0, duplicate 1; u2: ...': every message the
    server received is in one bucket, so the buckets beyond the usual three are named when they
    hold any (a lockstep agent's re-send after a slow second is a duplicate)."""
    return "messages: " + "; ".join(
        f"{v}: used {c.used}/{c.received}, late {c.late}, rejected {c.rejected}"
        + "".join(
            f", {name} {n}" for name, n in (("duplicate", c.duplicate), ("elsewhere", c.elsewhere)) if n
        )
        for v, c in diagnostics.vehicles.items()
    )
