"""Road-map change detection with and without the fleet's common residual (docs/roadmap.md).

    .venv/bin/python bench/roadmap_change_reference.py [--seeds training|report] [--out docs/roadmap.md]

The runs of bench/roadmap_acceptance.py's experiments 2 and 3 (six sharpening drives, then four
over a road raised by 0.5 m) are solved once with `pc` and turned into passes; the passes are then
applied to a fresh map for each variant of `RoadMapConfig`, so a variant costs seconds. Per variant:
changes flagged during the sharpening runs (all false), then after each raised-road run the raised
tiles flagged so far and the other tiles flagged so far. The training seeds chose
`change_reference` (on); `--seeds report` shows the report seeds, which chose nothing.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import roadmap_acceptance as acceptance
from docblock import publish

from coplane.evaluate.map_build import run_samples
from coplane.evaluate.runner import run_method
from coplane.recording.reader import Recording
from coplane.roadmap import MapBuilder, PassEvidence, RoadMap, RoadMapConfig, TileKey

MARK = "roadmap_change_reference"
VARIANTS = {
    "each pass's own z (`change_reference=false`)": {"change_reference": False},
    "common residual, 120 s (default)": {},
    "common residual, 600 s": {"change_reference_window_s": 600.0},
    "common residual, at least 60 passes": {"change_reference_min_passes": 60},
}


def passes_of(rec: Recording, config: RoadMapConfig) -> list[PassEvidence]:
    """The passes a map would take from `pc` on this recording."""
    builder = MapBuilder(config)
    for sample in run_samples(run_method(rec, "pc"), rec):
        builder.add(sample)
    return builder.flush()


def experiment_passes(
    seeds_name: str, work: Path | None, cfg: RoadMapConfig
) -> tuple[list[list[PassEvidence]], list[tuple[list[PassEvidence], set[TileKey]]]]:
    """The passes of experiment 2's sharpening runs, then of experiment 3's raised-road runs each
    with the tiles the raise lifts by more than 0.25 m (recordings made in `work`, or a temporary
    folder, and reused when there)."""
    seeds = acceptance.SEEDS[seeds_name]
    work = work or Path(tempfile.mkdtemp(prefix="coplane-change-"))
    sharpen = [
        acceptance.simulate(work / f"sharpen-{s}", s, 300.0, offset_s=600.0 * k)
        for k, s in enumerate(seeds["sharpen"])
    ]
    base = acceptance.truth_planes(acceptance.truth_points(sharpen, cfg.tile_size_m), cfg.tile_size_m)
    sharpen_passes = [passes_of(rec, cfg) for rec in sharpen]
    change: list[tuple[list[PassEvidence], set[TileKey]]] = []
    for k, seed in enumerate(seeds["change"]):
        offset = acceptance.CHANGE_OFFSET_S + 600.0 * k
        rec = acceptance.simulate(
            work / f"change-{seed}-{offset:.0f}", seed, 300.0, offset_s=offset, raises=(acceptance.RAISE,)
        )
        points = acceptance.truth_points([rec], cfg.tile_size_m)
        raised = {key for key, p in points.items() if key in base and acceptance.rise_at(base[key], p) > 0.25}
        change.append((passes_of(rec, cfg), raised))
    return sharpen_passes, change


def experiment_args(doc: str | None, default_seeds: str) -> argparse.Namespace:
    """--seeds training|report, --work DIR (recordings kept and reused), --out DOC."""
    ap = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", choices=("training", "report"), default=default_seeds)
    ap.add_argument("--work", type=Path, default=None, help="folder for the recordings (kept, reused)")
    ap.add_argument("--out", type=Path, default=None)
    return ap.parse_args()


def seeds_line(seeds_name: str) -> str:
    """The head of a table: which drives it comes from."""
    seeds = acceptance.SEEDS[seeds_name]
    return (
        f"{seeds_name} seeds: sharpening {', '.join(map(str, seeds['sharpen']))}, raised road "
        f"{', '.join(map(str, seeds['change']))} (4 vehicles, 300 s each, `pc`"
    )


def main() -> int:
    args = experiment_args(__doc__, "training")
    cfg = RoadMapConfig()
    sharpen_passes, change = experiment_passes(args.seeds, args.work, cfg)
    runs = " | ".join(f"run {k + 1}: raised / other" for k in range(len(change)))
    rows = [
        f"| variant | false changes, sharpening | {runs} |",
        "|---|---|" + "---|" * len(change),
    ]
    for label, kw in VARIANTS.items():
        road_map = RoadMap(dataclasses.replace(cfg, **kw))
        for passes in sharpen_passes:
            road_map.apply(passes)
        sharpening = sum(t.changes for t in road_map.tiles.values())
        before = {key: t.changes for key, t in road_map.tiles.items()}
        cells = []
        for passes, raised in change:
            road_map.apply(passes)
            flagged = {key for key, t in road_map.tiles.items() if t.changes > before.get(key, 0)}
            cells.append(f"{len(flagged & raised)} of {len(raised)} / {len(flagged - raised)}")
        rows.append(f"| {label} | {sharpening} | " + " | ".join(cells) + " |")
    publish(
        args.out,
        f"{MARK}_{args.seeds}",
        f"python bench/roadmap_change_reference.py --seeds {args.seeds} --out {args.out}",
        seeds_line(args.seeds) + ")",
        rows,
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
