"""`coplane map build|show`: the road-surface map every pass of the fleet refines (docs/roadmap.md)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from coplane.cli.options import progress_bars
from coplane.cli.render import console

map_app = typer.Typer(
    name="map",
    help="The road-surface map: build it from recordings, show its tiles.",
    no_args_is_help=True,
)


@map_app.command("build")
def build(
    recordings: Annotated[list[Path], typer.Argument(help="Fleet recordings, applied in the order given.")],
    out: Annotated[
        Path, typer.Option("--out", help="The map file (SQLite): created, or extended if it exists.")
    ],
    method: Annotated[str, typer.Option(help="The method whose solved positions are the evidence.")] = "pc",
    seed: Annotated[int, typer.Option(help="Seed for plane down-selection and RANSAC.")] = 0,
    dgnss: Annotated[
        bool | None, typer.Option(help="Force DGNSS on/off; default: on when the recording has a base.")
    ] = None,
    jobs: Annotated[
        int | None, typer.Option(min=1, help="Processes for the vehicle steps; default: one per core.")
    ] = None,
) -> None:
    """Build or extend a road-surface map from the fused positions of recordings.

    Each recording is solved with METHOD; every trustworthy vehicle-epoch (low covariance, a GNSS
    fix, not flagged) adds its pass through each tile. The map is written after each recording in
    one transaction, so an interrupted build keeps every recording it finished.
    """
    from coplane.evaluate.map_build import extend_map
    from coplane.evaluate.runner import run_method
    from coplane.methods import get_method
    from coplane.recording.reader import open_recording
    from coplane.store.roadmap_db import RoadMapDb

    spec = get_method(method)
    table = Table(title=f"map {out}")
    for col in ("recording", "method", "samples", "skipped", "passes", "changes"):
        table.add_column(col, justify="left" if col in ("recording", "method") else "right")
    recs = [open_recording(path) for path in recordings]  # a missing one is named before any build
    with RoadMapDb(out) as db:
        road_map = db.load()
        for path, rec in zip(recordings, recs, strict=True):
            run = run_method(
                rec,
                spec,
                seed=seed,
                dgnss=dgnss,
                jobs=jobs,
                progress=progress_bars(),
                road_map=road_map if spec.plane_map else None,
            )
            ext = extend_map(road_map, run, rec)
            db.write(road_map.take_dirty(), ext.changes, mapped_until=road_map.mapped_until)
            skipped = ", ".join(f"{k} {v}" for k, v in sorted(ext.skipped.items())) or "0"
            table.add_row(
                ext.recording, ext.method, str(ext.samples), skipped, str(ext.passes), str(len(ext.changes))
            )
            if not ext.passes and ext.samples > ext.skipped.get("already-mapped", 0):
                console.print(f"[yellow]{path}: no sample passed the map's trust filter ({skipped})[/yellow]")
                standalone = dgnss is False or (dgnss is None and rec.manifest.base is None)
                if standalone and ext.skipped.get("sigma-up"):
                    console.print(
                        f"[yellow]  {ext.skipped['sigma-up']} had a vertical sigma above max_sigma_up_m "
                        f"{road_map.config.max_sigma_up_m:g} m: without a base station the reported "
                        "covariance includes the broadcast atmosphere's residual, which the whole drive "
                        "shares, so a standalone drive is no evidence of the road at that level "
                        "(docs/roadmap.md, 'Without a base station')[/yellow]"
                    )
        stats = road_map.stats()
    console.print(table)
    console.print(", ".join(f"{k} {v}" for k, v in stats.items()))
    console.print(f"wrote {out}")


@map_app.command("show")
def show(
    map_file: Annotated[Path, typer.Argument(help="A map file made by `coplane map build`.")],
    out: Annotated[Path, typer.Option("--out", help="Folder for tiles.png and tiles.geojson.")] = Path(
        "out/map"
    ),
) -> None:
    """Write the map's tiles as a PNG coloured by their height sigma and as GeoJSON."""
    from coplane.evaluate.plots import plot_map_tiles
    from coplane.roadmap import tiles_geojson
    from coplane.store.roadmap_db import RoadMapDb

    with RoadMapDb(map_file, readonly=True) as db:
        road_map = db.load()
    features = tiles_geojson(road_map.tiles.values(), road_map.config)
    out.mkdir(parents=True, exist_ok=True)
    (out / "tiles.geojson").write_text(json.dumps(features) + "\n")
    png = plot_map_tiles(features, out / "tiles.png", title=map_file.name)
    console.print(", ".join(f"{k} {v}" for k, v in road_map.stats().items()))
    console.print(f"wrote {png} and {out / 'tiles.geojson'}")
