"""`coplane simulate`: simulate a fleet drive and write it as a fleet recording."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from coplane.cli.options import progress_bars
from coplane.cli.render import console
from coplane.errors import ConfigError
from coplane.sim.scenarios import DEFAULT_SCENARIO, SCENARIOS


def simulate_command(
    out: Annotated[Path, typer.Option("--out", help="Directory to write the fleet recording into.")],
    vehicles: Annotated[int, typer.Option("--vehicles", min=1, help="Number of vehicles (u1..uM).")] = 4,
    duration: Annotated[
        float, typer.Option("--duration", min=1.0, help="Seconds to simulate (1 Hz).")
    ] = 600.0,
    seed: Annotated[
        int, typer.Option("--seed", help="Random seed; the same seed gives identical files.")
    ] = 0,
    scenario: Annotated[
        str, typer.Option("--scenario", help=f"One of: {', '.join(sorted(SCENARIOS))}.")
    ] = DEFAULT_SCENARIO,
    start_offset: Annotated[
        float,
        typer.Option(
            "--start-offset",
            min=0.0,
            help="Start the drive this many seconds after the scenario's start: same roads, another sky.",
        ),
    ] = 0.0,
    doppler: Annotated[
        bool,
        typer.Option(
            help="Write Doppler observations; --no-doppler: pseudoranges and C/N0 only, as from a"
            " receiver or stream without Doppler (RTCM MSM4)."
        ),
    ] = True,
) -> None:
    """Simulate a fleet drive (GNSS, UWB, truth) and write it as a fleet recording."""
    from coplane.sim import run_simulation, write_recording
    from coplane.sim.write import check_out_dir

    if scenario not in SCENARIOS:
        raise ConfigError(f"unknown scenario {scenario!r}; known: {', '.join(sorted(SCENARIOS))}")
    check_out_dir(out.resolve())  # before the minutes of simulation, not after them
    t0 = time.perf_counter()
    try:
        result = run_simulation(
            scenario, vehicles, duration, seed, progress=progress_bars(), start_offset_s=start_offset
        )
    except ValueError as exc:  # sim reports bad arguments (a window past the ephemerides) as ValueError
        raise ConfigError(str(exc)) from exc
    t1 = time.perf_counter()
    path = write_recording(result, out, doppler)
    t2 = time.perf_counter()
    n_obs = sum(len(e.sats) for eps in result.vehicle_obs.values() for e in eps)
    n_ep = len(result.times)
    table = Table(title=f"simulated {scenario} (seed {seed})")
    table.add_column("item")
    table.add_column("value", justify="right")
    table.add_row("vehicles x epochs", f"{vehicles} x {n_ep}")
    table.add_row("satellites per vehicle epoch", f"{n_obs / max(1, vehicles * n_ep):.1f}")
    table.add_row("base epochs", str(len(result.base_obs)))
    table.add_row("UWB ranges", str(len(result.uwb)))
    table.add_row("simulate / write s", f"{t1 - t0:.1f} / {t2 - t1:.1f}")
    console.print(table)
    console.print(f"wrote {path}")
