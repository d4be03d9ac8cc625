"""What a raised-road run shows the map's change detector (docs/roadmap.md, "What the fleet shares
is not a change").

    .venv/bin/python bench/roadmap_change_evidence.py [--seeds training|report] [--work DIR]
        [--out docs/roadmap.md]

The runs of bench/roadmap_acceptance.py's experiments 2 and 3 (six sharpening drives, then four
over a road raised by 0.5 m) are solved with `pc` and their passes applied in order to a map with
the defaults, as `bench/roadmap_change_reference.py` does. Each pass's residual against its tile
(before it is added) is kept with the fleet's common residual it was tested against. Per
raised-road run, on the raised tiles: how many passes, when in the drive (s after its first
pass), how many came before the common residual was known (so were not tested), each vehicle's
mean corrected residual (residual - common residual) over its tested passes there, and the
raised tiles' mean; for scale, the spread of the same per-vehicle means over stretches of other
tiles of the run (each vehicle's passes cut into runs of as many passes as it made on the raised
tiles), and how many of the raised tiles' passes the tiles refused as outliers. A vehicle's passes over neighbouring tiles seconds apart share its error, so a stretch is
worth about one sample per vehicle, not one per pass: a 0.5 m raise stands out of a run only if
that spread is well below 0.5 m.
"""

from __future__ import annotations

import argparse
import statistics
import sys
from collections import defaultdict
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import roadmap_acceptance as acceptance
from docblock import publish
from roadmap_change_reference import experiment_args, experiment_passes, seeds_line

from coplane.roadmap import PassEvidence, RoadMap, RoadMapConfig, TileKey, TileUpdate
from coplane.roadmap.reference import ZReference

MARK = "roadmap_change_evidence"

# vehicle, time s, residual m, common residual m (None: unknown), added to the tile (False: an outlier)
Row = tuple[str, float, float, float | None, bool]


def applied(road_map: RoadMap, passes: list[PassEvidence]) -> list[tuple[TileKey, Row]]:
    """`RoadMap.apply`, keeping each pass on a usable tile with its residual and the common
    residual it was tested against."""
    out: list[tuple[TileKey, Row]] = []

    def keep(p: PassEvidence, upd: TileUpdate, ref: ZReference | None, usable: bool) -> None:
        if usable and p.key is not None:
            offset = None if ref is None else ref.offset_m
            out.append((p.key, (p.vehicle_id, p.time_s, upd.residual_m, offset, upd.accepted)))

    road_map.apply(passes, on_pass=keep)
    return out


def stretch_means(rows: list[Row], length: int) -> list[float]:
    """Each vehicle's tested passes (in time order) cut into stretches of `length`: their mean
    corrected residuals."""
    by_vehicle: dict[str, list[float]] = defaultdict(list)
    for vid, _, r, off, _ in sorted(rows, key=lambda x: x[1]):
        if off is not None:
            by_vehicle[vid].append(r - off)
    out = []
    for vals in by_vehicle.values():
        out += [statistics.fmean(vals[i : i + length]) for i in range(0, len(vals) - length + 1, length)]
    return out


def main() -> int:
    args: argparse.Namespace = experiment_args(__doc__, "report")  # --help prints the usage, runs nothing
    seeds = acceptance.SEEDS[args.seeds]
    cfg = RoadMapConfig()
    sharpen_passes, change = experiment_passes(args.seeds, args.work, cfg)
    road_map = RoadMap(cfg)
    for passes in sharpen_passes:
        road_map.apply(passes)
    rows_md = [
        "| run (seed) | raised tiles | passes on them | s into the drive | untested (no common residual yet)"
        " | each vehicle's mean corrected residual there (m) | raised tiles' mean (m) | per-vehicle stretch"
        " means elsewhere: SD (m) | beyond `outlier_z`, not added |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for k, (seed, (passes, raised)) in enumerate(zip(seeds["change"], change, strict=True)):
        got = applied(road_map, passes)
        t0 = min(row[1] for _, row in got)
        on = [row for key, row in got if key in raised]
        off = [row for key, row in got if key not in raised]
        tested = [row for row in on if row[3] is not None]
        per_vehicle: dict[str, list[float]] = defaultdict(list)
        for vid, _, r, ref, _ in tested:
            assert ref is not None
            per_vehicle[vid].append(r - ref)
        means = {vid: statistics.fmean(v) for vid, v in sorted(per_vehicle.items())}
        length = max(1, round(len(tested) / max(1, len(means))))
        spread = statistics.pstdev(stretch_means(off, length))
        times = [row[1] - t0 for row in on]
        rows_md.append(
            f"| {k + 1} ({seed}) | {len(raised)} | {len(on)} | {min(times):.0f}-{max(times):.0f} "
            f"| {len(on) - len(tested)} | {', '.join(f'{v} {m:+.2f}' for v, m in means.items())} "
            f"| {statistics.fmean([r - ref for _, _, r, ref, _ in tested if ref is not None]):+.2f} | {spread:.2f} "
            f"| {sum(1 for row in on if not row[4])} |"
        )
    publish(
        args.out,
        f"{MARK}_{args.seeds}",
        f"python bench/roadmap_change_evidence.py --seeds {args.seeds} --out {args.out}",
        seeds_line(args.seeds) + f", the map's defaults; the raise is {acceptance.RAISE.dz_m} m)",
        rows_md,
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
