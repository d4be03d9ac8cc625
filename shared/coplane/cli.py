"""The `coplane` command. Each subcommand is a thin wrapper over library functions."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer
from rich.console import Console
from rich.table import Table

app = typer.Typer(
    name="coplane",
    help="Plane-constraint-aided cooperative positioning for vehicle fleets.",
    no_args_is_help=True,
    add_completion=False,
)
console = Console()


def _register_simulate() -> None:
    from coplane.sim.cli import simulate_command

    app.command("simulate")(simulate_command)


_register_simulate()


@app.callback()
def main(
    verbose: Annotated[
        bool, typer.Option("--verbose", "-v", help="Log input problems as they are found.")
    ] = False,
) -> None:
    """coplane: replay fleet recordings, run SPP and the cooperative estimators, serve results."""
    logging.basicConfig(
        level=logging.WARNING if verbose else logging.ERROR, format="%(levelname)s %(name)s: %(message)s"
    )


@app.command()
def version() -> None:
    """Print the coplane version."""
    from coplane import __version__

    typer.echo(__version__)


def _fmt(x: float) -> str:
    return "-" if not np.isfinite(x) else f"{x:.2f}"


@app.command()
def spp(
    recording: Annotated[Path, typer.Argument(help="Fleet recording directory (with fleet.toml).")],
    out: Annotated[
        Path,
        typer.Option(help="RTKLIB .pos file; with several vehicles, one file per vehicle (<stem>_<id>.pos)."),
    ],
    vehicle: Annotated[list[str] | None, typer.Option(help="Vehicle id (repeatable); default all.")] = None,
    dgnss: Annotated[
        bool, typer.Option(help="Apply DGNSS corrections from the recording's base station.")
    ] = False,
    fde: Annotated[bool, typer.Option(help="RAIM fault detection and exclusion.")] = True,
) -> None:
    """Single point positioning of each vehicle; writes .pos and prints availability and accuracy."""
    from dataclasses import replace

    from coplane.evaluate.metrics import accuracy
    from coplane.evaluate.solution_files import Q_DGPS, Q_SINGLE, PosRecord, write_pos
    from coplane.evaluate.spp_run import run_spp
    from coplane.gnss.epoch_solver import EpochSolverOptions
    from coplane.recording.problems import RecordingError
    from coplane.recording.reader import open_recording

    try:
        rec = open_recording(recording)
        opts = EpochSolverOptions()
        opts = replace(opts, spp=replace(opts.spp, raim="fde" if fde else "off"))
        runs = run_spp(rec, vehicle, dgnss=dgnss, options=opts, progress=True)
    except (RecordingError, KeyError, ValueError) as exc:
        console.print(f"[red]error:[/red] {exc}")
        raise typer.Exit(2) from exc
    table = Table(title=f"SPP {'DGNSS' if dgnss else 'standalone'}: {rec.manifest.name}")
    for col in (
        "vehicle",
        "epochs",
        "fixes",
        "avail %",
        "H RMSE m",
        "V RMSE m",
        "CEP95 m",
        "max H m",
        "max V m",
        "no fix: reasons",
    ):
        table.add_column(col, justify="right" if col not in ("vehicle", "no fix: reasons") else "left")
    for vid, run in runs.items():
        fixes = run.fixes()
        target = out if len(runs) == 1 else out.with_name(f"{out.stem}_{vid}{out.suffix or '.pos'}")
        write_pos(
            target,
            (
                PosRecord(
                    r.spp.time, r.spp.position, r.spp.covariance, Q_DGPS if dgnss else Q_SINGLE, r.spp.n_used
                )
                for r in run.results.values()
                if r.spp.ok
            ),
            inputs=[str(rec.manifest.vehicle(vid).obs)],
            mode="dgps" if dgnss else "single",
        )
        truth = rec.truth_at(vid)
        st = accuracy(fixes, {t: np.asarray(p) for t, p in truth.items()}) if truth else None
        avail = 100.0 * len(fixes) / run.n_epochs if run.n_epochs else 0.0
        reasons = ", ".join(f"{k} x{n}" for k, n in run.no_solution.most_common(3))
        table.add_row(
            vid,
            str(run.n_epochs),
            str(len(fixes)),
            f"{avail:.1f}",
            *(
                _fmt(x)
                for x in (
                    (st.h_rmse_m, st.v_rmse_m, st.cep95_m, st.h_max_m, st.v_max_m) if st else (np.nan,) * 5
                )
            ),
            reasons or "-",
        )
        console.print(f"wrote {target}")
    console.print(table)
    if rec.problems:
        console.print(
            f"[yellow]{rec.problems.total} input problems[/yellow]: "
            + ", ".join(f"{k} x{n}" for k, n in rec.problems.counts.most_common())
        )


def _recording_or_default(recording: Path | None) -> Path:
    if recording is not None:
        return recording
    from coplane.sim.generate import ensure_default_recording

    return ensure_default_recording()


def _print_accuracy(title: str, stats: dict, vehicles: list[str]) -> None:
    """One table per vehicle (rows: methods); with a single method, one table (rows: vehicles)."""
    from coplane.evaluate.report import TABLE_COLUMNS

    def row(st: Any) -> list[str]:
        vals = (st.h_rmse_m, st.v_rmse_m, st.cep95_m, st.h_max_m, st.v_max_m)
        return [*(_fmt(x) for x in vals), f"{100 * st.availability:.1f}"]

    if len(stats) == 1:
        ((label, per),) = stats.items()
        table = Table(title=f"{title}: {label}")
        table.add_column("vehicle")
        for col in TABLE_COLUMNS:
            table.add_column(col, justify="right")
        for vid in vehicles:
            if vid in per:
                table.add_row(vid, *row(per[vid]))
        console.print(table)
        return
    for vid in vehicles:
        table = Table(title=f"{title}: vehicle {vid}")
        table.add_column("method")
        for col in TABLE_COLUMNS:
            table.add_column(col, justify="right")
        for label, per in stats.items():
            if vid in per:
                table.add_row(label, *row(per[vid]))
        console.print(table)


@app.command("eval")
def eval_(
    recording: Annotated[
        Path | None, typer.Argument(help="Fleet recording; default: the bundled one.")
    ] = None,
    methods: Annotated[
        str, typer.Option(help="Comma-separated methods (see docs/fgo.md).")
    ] = "non-cp,mci,pc,pc-no-ir,pc-no-ir-no-fe",
    interruption: Annotated[
        str, typer.Option(help="Comma-separated ranging interruption rates in %, e.g. 0,20,40,60,80,100.")
    ] = "0",
    vehicle: Annotated[
        list[str] | None, typer.Option(help="Vehicles for tables and figures (repeatable); default all.")
    ] = None,
    out: Annotated[
        Path, typer.Option(help="Output folder: accuracy.md/json, figures, solutions/<method>/<vehicle>.csv.")
    ] = Path("out/eval"),
    seed: Annotated[int, typer.Option(help="Seed for plane down-selection, RANSAC and interruption.")] = 0,
    dgnss: Annotated[
        bool | None, typer.Option(help="Force DGNSS on/off; default: on when the recording has a base.")
    ] = None,
    jobs: Annotated[
        int | None,
        typer.Option(
            min=1, help="Processes for the vehicle steps (same results for any); default: one per core."
        ),
    ] = None,
) -> None:
    """Run the estimators in-process and write the paper's tables and figures."""
    from coplane.evaluate.evaluation import evaluate
    from coplane.recording.problems import RecordingError
    from coplane.recording.reader import open_recording

    try:
        rates = [float(x) / 100.0 for x in interruption.split(",") if x.strip()]
        if any(not 0.0 <= r <= 1.0 for r in rates):
            raise ValueError("interruption rates must be within 0..100 %")
        rec = open_recording(_recording_or_default(recording))
        names = [m.strip() for m in methods.split(",") if m.strip()]
        ev = evaluate(
            rec, names, rates, out, seed=seed, vehicles=vehicle, dgnss=dgnss, progress=True, jobs=jobs
        )
    except (RecordingError, KeyError, ValueError) as exc:
        console.print(f"[red]error:[/red] {exc}")
        raise typer.Exit(2) from exc
    shown = list(vehicle or [v.id for v in rec.manifest.vehicles if rec.truth_at(v.id)])
    _print_accuracy(rec.manifest.name, ev.stats, shown)
    for r in ev.runs:
        console.print(f"{r.label}: {r.n_epochs} epochs in {r.wall_time_s:.1f} s")
    console.print(f"wrote {out}/accuracy.md, {len(ev.figures)} figures and solutions/")


@app.command()
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
        path = _recording_or_default(recording).resolve()
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
        _print_accuracy(
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


@app.command()
def compose(
    out: Annotated[Path, typer.Option(help="Where to write the compose file.")] = Path("docker-compose.yml"),
    method: Annotated[str, typer.Option(help="Estimator method.")] = "pc",
    pace: Annotated[str, typer.Option(help="lockstep or realtime.")] = "realtime",
) -> None:
    """Write docker-compose.yml for the bundled recording from the launcher's own service list."""
    import yaml

    from coplane.fleet import compose_document, fleet_of
    from coplane.sim.generate import bundled_default_path

    _, vehicles = fleet_of(bundled_default_path())
    doc = compose_document(vehicles, method, pace)
    header = "# Generated by `coplane compose` from coplane.fleet.fleet_services: edit that, not this file.\n"
    out.write_text(header + yaml.safe_dump(doc, sort_keys=False, width=200))
    console.print(f"wrote {out} ({len(doc['services'])} services)")


if __name__ == "__main__":
    app()
