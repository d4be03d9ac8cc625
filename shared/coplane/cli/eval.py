"""`coplane eval`: every method in-process on one recording; the paper's tables and figures."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from coplane.cli.options import (
    FORMAT_HELP,
    interruption_rates,
    method_names,
    progress_bars,
    recording_or_default,
    solution_formats,
)
from coplane.cli.render import STRICT_HELP, check_input, console, print_accuracy, print_problems


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
    strict: Annotated[bool, typer.Option(help=STRICT_HELP)] = False,
    fmt: Annotated[
        str,
        typer.Option("--format", help=FORMAT_HELP),
    ] = "",
    fgo: Annotated[
        list[str] | None,
        typer.Option(
            help="Change a factor-graph setting of every FGO method, key=value (repeatable), e.g."
            " fde_k_long=1.5 or height_link_max_m=50; see FgoConfig and docs/fgo.md. Baselines are"
            " unaffected.",
        ),
    ] = None,
    map_file: Annotated[
        Path | None,
        typer.Option(
            "--map", help="Road-surface map (`coplane map build`) for the map methods pc-map, pc-self-map."
        ),
    ] = None,
    truth: Annotated[
        list[str] | None,
        typer.Option(
            help="What the errors are measured against: 'recording' (its truth files, the default), 'rtk'"
            " (RTKLIB's carrier-phase RTK to the base, where its forward and backward runs agree; for drives"
            " with dual-frequency RINEX and a base but no surveyed trajectory), and/or ID=FILE (repeatable):"
            " vehicle ID's reference trajectory from another tool, an RTKLIB .pos (its fixed rows, if it has"
            " any), an Inertial Explorer text export or a truth CSV; ID=x,y,z or ID=lat,lon,h: the surveyed"
            " point a static receiver stood on.",
        ),
    ] = None,
) -> None:
    """Run the estimators in-process and write the paper's tables and figures."""
    from coplane.evaluate.evaluation import evaluate
    from coplane.evaluate.truth import parse_truth_choice
    from coplane.fgo.overrides import parse_fgo_overrides
    from coplane.recording.health import health_warnings, input_health
    from coplane.recording.reader import open_recording

    rates = interruption_rates(interruption)
    fgo_changes = parse_fgo_overrides(fgo or [])
    formats = solution_formats(fmt)
    truth_choice = parse_truth_choice(truth)
    road_map = None
    if map_file is not None:
        from coplane.store.roadmap_db import RoadMapDb

        with RoadMapDb(map_file, readonly=True) as db:
            road_map = db.load()
    rec = open_recording(recording_or_default(recording))
    ev = evaluate(
        rec,
        method_names(methods),
        rates,
        out,
        seed=seed,
        vehicles=vehicle,
        dgnss=dgnss,
        progress=progress_bars(),
        jobs=jobs,
        road_map=road_map,
        fgo=fgo_changes,
        truth=truth_choice,
    )
    if formats:
        from coplane.evaluate.solution_files import write_solution_formats

        write_solution_formats(ev.runs, rec, out, formats)
    for note in ev.notes.values():
        typer.echo(note, err=True)
    print_accuracy(ev.recording, ev.stats, ev.shown)
    for r in ev.runs:
        console.print(f"{r.label}: {r.n_epochs} epochs in {r.wall_time_s:.1f} s")
    console.print(
        f"wrote {out}/accuracy.md, accuracy_by_environment.md (pooled, with p99 and max),"
        f" exclusions.md (the satellites each estimate left out), {len(ev.figures)} figures and solutions/"
    )
    print_problems(rec.problems.counts)
    fixes = sum(len(p) for r in ev.runs for p in r.positions.values())
    check_input(health_warnings(input_health(rec), fixes), strict)
