"""`coplane loadgen`: many vehicles of a recording as agents in one process (a load test)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from coplane.cli.options import recording_or_default
from coplane.cli.render import console, err_console
from coplane.typing import Pace


def loadgen(
    recording: Annotated[
        Path | None, typer.Argument(help="Fleet recording; default: the bundled one.")
    ] = None,
    insecure: Annotated[
        bool,
        typer.Option(
            help="Required: one process speaks for every vehicle, so it cannot hold their certificates; "
            "run load tests on an insecure test bus only."
        ),
    ] = False,
    connect: Annotated[str, typer.Option(help="Zenoh router endpoint.")] = "tcp/127.0.0.1:7447",
    vehicles: Annotated[int, typer.Option(min=0, help="Only the first N vehicles (0: all).")] = 0,
    method: Annotated[str, typer.Option(help="Estimator method (the fusion servers').")] = "pc",
    pace: Annotated[Pace, typer.Option(help="lockstep or realtime.")] = "lockstep",
    speed: Annotated[float, typer.Option(min=0.01, help="Realtime replay speed factor.")] = 1.0,
    regions: Annotated[
        bool, typer.Option(help="Publish by region (servers started with --regions).")
    ] = False,
    region_size: Annotated[float, typer.Option("--region-size", min=100.0, help="Region edge (m).")] = 4000.0,
    region_margin: Annotated[
        float, typer.Option("--region-margin", min=0.0, help="Copy to regions this close (m).")
    ] = 500.0,
    json_out: Annotated[
        Path | None, typer.Option("--json", help="Also write the summary as JSON here.")
    ] = None,
) -> None:
    """Replay every vehicle of a recording as its own VehicleStep on one bus session (docs/scale.md)."""
    from coplane.bus.security import BusSecurity, use_security
    from coplane.errors import ConfigError
    from coplane.runtime import setup_logging, steady_state_gc, stop_event
    from coplane.vehicle_agent.loadgen import LoadGenerator
    from coplane.vehicle_agent.settings import LoadgenSettings

    if not insecure:
        raise ConfigError(
            "coplane loadgen speaks for every vehicle of the recording, so it cannot use their certificates:"
            " run it on a test bus with --insecure (routers and servers started with --insecure too)"
        )
    err_console.print(
        "[bold red]WARNING: --insecure: plain TCP, no authentication, no access control[/bold red]"
    )
    settings = LoadgenSettings(
        recording=recording_or_default(recording),
        vehicles=vehicles,
        method=method,
        connect=[connect],
        pace=pace,  # type: ignore[arg-type]
        speed=speed,
        regions=regions,
        region_size_m=region_size,
        region_margin_m=region_margin,
    )
    setup_logging("loadgen", settings.log_level)  # its warnings (an epoch left unanswered) as JSON lines
    with use_security(BusSecurity(insecure=True)):
        generator = LoadGenerator(settings, stop_event())
        steady_state_gc()  # started: what the collector need not scan again
        stats = generator.run()
    summary = stats.summary()
    table = Table(title=f"loadgen: {summary['vehicles']} vehicles, {summary['epochs']} epochs ({pace})")
    table.add_column("item")
    table.add_column("value", justify="right")
    for k, v in summary.items():
        table.add_row(k, str(v))
    console.print(table)
    if json_out is not None:
        json_out.write_text(json.dumps(summary, indent=2) + "\n")
