"""`coplane fleet`: replay a recording as a fleet of processes over Zenoh (coplane.fleet.run_fleet)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from coplane.cli.options import recording_or_default
from coplane.cli.render import console, err_console, print_accuracy

if TYPE_CHECKING:
    from coplane.fleet import FleetResult


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
    from tqdm import tqdm

    from coplane.fleet import FleetOptions, run_fleet

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
    )
    bars: list[Any] = []  # the progress bar, once the replay's length is known

    def progress(done: int, total: int) -> None:
        if not bars:
            bars.append(tqdm(total=total, desc=f"fleet {method} ({pace})", unit="epoch"))
        bars[0].update(done - bars[0].n)

    def close_bar() -> None:
        while bars:
            bars.pop().close()

    def keep_serving(result: FleetResult) -> None:
        close_bar()
        _render(result)
        console.print(f"serving: API on {result.api_url} (Ctrl-C to stop)")
        try:
            while True:
                time.sleep(1.0)
        except KeyboardInterrupt:
            pass

    try:
        result = run_fleet(options, progress, keep_serving if serve else None)
    finally:
        close_bar()
    if not serve:
        _render(result)


def _render(result: FleetResult) -> None:
    if result.failed_agents:
        err_console.print(f"[red]agents failed:[/red] {result.failed_agents} (see --logs)")
    print_accuracy(
        f"{result.recording_name} (fleet over Zenoh)", {result.method: result.stats}, result.truth_vehicles
    )
    if result.diagnostics is not None:
        console.print(
            "messages: "
            + ", ".join(
                f"{v}: used {c.used}/{c.received}, late {c.late}, rejected {c.rejected}"
                for v, c in result.diagnostics.vehicles.items()
            )
        )
    if result.solutions_dir is not None:
        console.print(f"wrote {result.solutions_dir}/")
