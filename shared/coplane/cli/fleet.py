"""`coplane fleet`: replay a recording as a fleet of processes over Zenoh."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from coplane.cli.options import recording_or_default
from coplane.cli.render import console, print_accuracy


def fleet(
    recording: Annotated[
        Path | None, typer.Argument(help="Fleet recording; default: the bundled one.")
    ] = None,
    method: Annotated[str, typer.Option(help="Estimator method.")] = "pc",
    pace: Annotated[str, typer.Option(help="lockstep (deterministic) or realtime.")] = "lockstep",
    speed: Annotated[float, typer.Option(help="Realtime speed factor.")] = 1.0,
    serve: Annotated[bool, typer.Option(help="Keep the API (and the bus) running after the replay.")] = False,
    api: Annotated[bool, typer.Option(help="Start the HTTP API.")] = True,
    api_port: Annotated[int, typer.Option(help="API port.")] = 8000,
    port: Annotated[int, typer.Option(help="Zenoh router port (0: any free port).")] = 7447,
    out: Annotated[Path | None, typer.Option(help="Write solutions/<method>/<vehicle>.csv here.")] = None,
    logs: Annotated[Path | None, typer.Option(help="Folder for each process's JSON log.")] = None,
    seed: Annotated[int, typer.Option(help="Seed (planes, interruption).")] = 0,
    interruption: Annotated[float, typer.Option(help="Ranging interruption rate in %.")] = 0.0,
) -> None:
    """Replay a recording as a fleet of processes over Zenoh and print the accuracy table."""
    import time

    from tqdm import tqdm

    from coplane.evaluate.report import run_stats, write_solutions
    from coplane.fleet import (
        Collector,
        FleetProcesses,
        fleet_of,
        fleet_services,
        free_port,
        router_spec,
        wait_for_port,
    )
    from coplane.methods import get_method
    from coplane.recording.reader import open_recording
    from coplane.replay import vehicle_schedule

    if pace not in ("lockstep", "realtime"):
        console.print("[red]error:[/red] --pace must be lockstep or realtime")
        raise typer.Exit(2)
    from coplane.recording.problems import RecordingError

    try:
        get_method(method)
        path = recording_or_default(recording).resolve()
        rec = open_recording(path)
        fleet_name, vehicles = fleet_of(path)
    except (RecordingError, ValueError) as exc:
        console.print(f"[red]error:[/red] {exc}")
        raise typer.Exit(2) from exc
    n_epochs = len(
        {t for v in vehicles for t, _ in vehicle_schedule(rec.vehicle_epochs(v), rec.manifest.interval_s)}
    )
    port = port or free_port()
    connect = f"tcp/127.0.0.1:{port}"
    procs = FleetProcesses(log_dir=logs)
    try:
        procs.start(router_spec(port))
        wait_for_port(port)
        collector = Collector(fleet_name, method, connect)
        start = time.time() + 5.0 if pace == "realtime" else None  # shared origin once processes are up
        for spec in fleet_services(
            path, method, pace, speed, connect, vehicles, api, api_port, seed, interruption / 100, start
        ):
            procs.start(spec)
        agents = [n for n in procs.procs if n.startswith("agent-")]
        with tqdm(total=n_epochs, desc=f"fleet {method} ({pace})", unit="epoch") as bar:
            while any(procs.procs[a].poll() is None for a in agents):
                time.sleep(0.2)
                bar.update(collector.epochs - bar.n)
            time.sleep(0.5)
            bar.update(collector.epochs - bar.n)
        if not serve:
            procs.stop("fusion-server")  # it publishes its final diagnostics on the way out
            time.sleep(0.3)
        failed = {a: procs.procs[a].returncode for a in agents if procs.procs[a].returncode}
        if failed:
            console.print(f"[red]agents failed:[/red] {failed} (see --logs)")
        stats = {method: run_stats(collector.run, rec)}
        print_accuracy(
            f"{rec.manifest.name} (fleet over Zenoh)", stats, [v for v in vehicles if rec.truth_at(v)]
        )
        if collector.diag is not None:
            d = collector.diag
            console.print(
                "messages: "
                + ", ".join(
                    f"{v}: used {c.used}/{c.received}, late {c.late}, rejected {c.rejected}"
                    for v, c in d.vehicles.items()
                )
            )
        if out is not None:
            write_solutions(collector.run, out)
            console.print(f"wrote {out}/solutions/{method}/")
        if serve:
            console.print(f"serving: API on http://127.0.0.1:{api_port} (Ctrl-C to stop)")
            try:
                while True:
                    time.sleep(1.0)
            except KeyboardInterrupt:
                pass
        collector.close()
    finally:
        procs.stop_all()
