"""Issue 14's acceptance: a road-surface map built on some runs, used on others.

    .venv/bin/python bench/roadmap_acceptance.py              # writes docs/results.md's road-map section, ~2 min
    .venv/bin/python bench/roadmap_acceptance.py --training   # the seeds the map defaults were checked on

Three experiments, each on simulated urban-loop drives whose errors are independent of the map's
(other seeds, another time of day):

1. **Map use.** A map is built from one 600 s run (method `pc`) and the methods are evaluated on
   another run over the same roads, 45 minutes later: plane availability on mapped roads,
   `pc-map` against `pc`, `pc-self-map` against `non-cp`. (1b, bench/roadmap_build_length.py:
   maps from other single drives, of 10, 20 and 40 minutes, on the same use drive.)
2. **Sharpening.** A map is extended run after run; after each, the tiles' height sigma and
   their error against the simulator's true road surface where the vehicles drive; then (2b) the
   sharpened map on experiment 1's use drive.
3. **Change.** A 300 m section is raised by 0.5 m; runs over the raised road extend the map one
   after another: when its tiles are flagged and re-learned, and the error of `pc-map` there
   against `pc`.

Seeds: the map's defaults (RoadMapConfig; max_use_sigma_m was chosen there) were checked on `--training` (build 111, use 112,
sharpening 121-126, change 141-144, build drives 113-115); the report uses the others (511, 512, 521-526,
541-544, 513-515).
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from coplane.evaluate.map_build import extend_map, plane_sources
from coplane.evaluate.metrics import fleet_errors, pooled_stats
from coplane.evaluate.runner import MethodRun, run_method
from coplane.plane.history import project_to_road
from coplane.recording.reader import Recording, open_recording
from coplane.roadmap import RoadMap, RoadMapConfig, TileKey, tile_of_ecef
from coplane.roadmap.grid import tile_frame
from coplane.sim.generate import run_simulation, write_recording
from coplane.sim.road import RoadRaise

DOCS = Path(__file__).resolve().parents[1] / "docs"
SCENARIO = "urban-loop"
SEEDS = {
    "report": {
        "build": 511,
        "use": 512,
        "sharpen": (521, 522, 523, 524, 525, 526),
        "change": (541, 542, 543, 544),
        "length": (513, 514, 515),
    },
    "training": {
        "build": 111,
        "use": 112,
        "sharpen": (121, 122, 123, 124, 125, 126),
        "change": (141, 142, 143, 144),
        "length": (113, 114, 115),
    },
}
USE_OFFSET_S = 45 * 60.0  # the evaluation run is 45 minutes after the build run
RAISE = RoadRaise(s_start_m=400.0, s_end_m=700.0, dz_m=0.5)
CHANGE_OFFSET_S = 3600.0  # the raised-road runs start an hour after the first sharpening run


def simulate(out: Path, seed: int, duration_s: float, offset_s: float = 0.0, raises: tuple = ()) -> Recording:
    """One 4-vehicle urban-loop recording (reused when it exists)."""
    if not (out / "fleet.toml").exists():
        res = run_simulation(SCENARIO, 4, duration_s, seed, start_offset_s=offset_s, road_raise=raises)
        write_recording(res, out)
    return open_recording(out)


def pooled_rmse(run: MethodRun, rec: Recording, keep=None) -> tuple[float, float, int]:
    """Pooled horizontal and vertical RMSE over every vehicle (only epochs `keep(vid, t)` accepts)."""
    truth = {v.id: {t: np.asarray(p) for t, p in rec.truth_at(v.id).items()} for v in rec.manifest.vehicles}
    s = pooled_stats(fleet_errors(run.positions, truth, keep))
    return s.h_rmse_m, s.v_rmse_m, s.n


def truth_points(recs: list[Recording], size_m: float) -> dict[TileKey, np.ndarray]:
    """The simulator's true road points (truth antenna positions moved down by the antenna height),
    ECEF, grouped by tile: where the vehicles actually drive, which is where a map plane is used."""
    pts: dict[TileKey, list[np.ndarray]] = defaultdict(list)
    for rec in recs:
        for v in rec.manifest.vehicles:
            for p in rec.truth_at(v.id).values():
                road = project_to_road(np.asarray(p), v.antenna_height_m)
                pts[tile_of_ecef(road, size_m)].append(road)
    return {k: np.array(v) for k, v in pts.items()}


def map_errors(road_map: RoadMap, points: dict[TileKey, np.ndarray]) -> list[tuple[int, float, float]]:
    """(passes, mean sigma, mean height error) of every usable tile at the true road points inside it.

    The error is taken where vehicles drive, not at the tile centre: a tile seen from one lane knows
    its height along that lane, and neither the map nor a plane fitted to true points there can
    say what lies 10 m across the road."""
    cfg = road_map.config
    rows = []
    for key, pts in points.items():
        tile = road_map.tiles.get(key)
        if tile is None or not tile.usable(cfg):
            continue
        errs, sigs = [], []
        for p in pts:
            e, n, u = tile.local_of_ecef(p, cfg)
            h, sig = tile.height_at(float(e), float(n), cfg)
            errs.append(h - (float(u) + tile.h0_m))
            sigs.append(sig)
        rows.append((tile.n_passes, float(np.mean(sigs)), float(np.mean(errs))))
    return rows


def truth_planes(
    points: dict[TileKey, np.ndarray], size_m: float
) -> dict[TileKey, tuple[np.ndarray, np.ndarray]]:
    """Per tile: a least-squares plane through its true road points (tile frame: origin, rotation,
    theta for u = theta0 + theta1 e + theta2 n); min-norm where the points lie on one line."""
    out = {}
    for key, pts in points.items():
        if len(pts) < 3:
            continue
        origin, rot = tile_frame(key, size_m)
        enu = (pts - origin) @ rot.T
        a = np.column_stack([np.ones(len(enu)), enu[:, 0], enu[:, 1]])
        theta, *_ = np.linalg.lstsq(a, enu[:, 2], rcond=None)
        out[key] = (origin, rot, theta)
    return out


def rise_at(plane: tuple, pts: np.ndarray) -> float:
    """Mean height of `pts` above a truth plane (the road's change there)."""
    origin, rot, theta = plane
    enu = (pts - origin) @ rot.T
    return float(np.mean(enu[:, 2] - (theta[0] + theta[1] * enu[:, 0] + theta[2] * enu[:, 1])))


@dataclass
class Line:
    text: str


def experiment_use(work: Path, seeds: dict, lines: list[str]) -> tuple[Recording, dict[str, MethodRun]]:
    build = simulate(work / f"build-{seeds['build']}", seeds["build"], 600.0)
    use = simulate(work / f"use-{seeds['use']}", seeds["use"], 300.0, USE_OFFSET_S)
    road_map = RoadMap(RoadMapConfig())
    t0 = time.perf_counter()
    ext = extend_map(road_map, run_method(build, "pc"), build)
    build_s = time.perf_counter() - t0
    stats = road_map.stats()
    lines += [
        f"### 1. Map use: built from seed {seeds['build']} (600 s), used on seed {seeds['use']} (300 s, 45 min later)",
        "",
        f"Map: {ext.samples} solved vehicle-epochs, {ext.passes} passes, "
        + ", ".join(f"{k} {v}" for k, v in stats.items())
        + f"; skipped samples: {dict(ext.skipped) or 0}; built in {build_s:.0f} s.",
        "",
    ]
    cfg = road_map.config

    def mapped(vid: str, t) -> bool:
        p = use.truth_at(vid).get(t)
        if p is None:
            return False
        h = use.manifest.vehicle(vid).antenna_height_m
        tile = road_map.tile_at(project_to_road(np.asarray(p), h))
        return tile is not None and tile.usable(cfg)

    runs = {
        m: run_method(use, m, road_map=road_map if m.endswith("-map") else None)
        for m in ("non-cp", "mci", "pc", "pc-self", "pc-map", "pc-self-map")
    }
    lines += [
        "| method | H RMSE (m) | V RMSE (m) | epochs | plane from map / fitted / none |",
        "|---|---|---|---|---|",
    ]
    res = {}
    for m, run in runs.items():
        h, v, n = pooled_rmse(run, use)
        res[m] = (h, v)
        src = plane_sources(run)
        lines.append(
            f"| {m} | {h:.2f} | {v:.2f} | {n} | {src.get('map', 0)} / {src.get('fleet', 0) + src.get('self', 0)} / {src.get('none', 0)} |"
        )
    lines.append("")
    # availability on mapped roads: epochs whose true position lies in a usable tile
    n_map = n_avail = 0
    for vid, by_t in runs["pc-map"].planes.items():
        for t, rep in by_t.items():
            if mapped(vid, t):
                n_map += 1
                n_avail += rep.status != "unavailable"
    pc_avail = sum(
        rep.status != "unavailable"
        for vid, by_t in runs["pc"].planes.items()
        for t, rep in by_t.items()
        if mapped(vid, t)
    )
    checks = [
        (
            "plane availability on mapped roads (pc-map)",
            n_avail / max(1, n_map),
            ">= 0.95",
            n_avail / max(1, n_map) >= 0.95,
        ),
        (
            "pc-map V / pc V",
            res["pc-map"][1] / res["pc"][1],
            "<= 0.5",
            res["pc-map"][1] <= 0.5 * res["pc"][1],
        ),
        ("pc-map H / pc H", res["pc-map"][0] / res["pc"][0], "<= 1.0", res["pc-map"][0] <= res["pc"][0]),
        (
            "pc-self-map V / non-cp V",
            res["pc-self-map"][1] / res["non-cp"][1],
            "<= 0.5",
            res["pc-self-map"][1] <= 0.5 * res["non-cp"][1],
        ),
    ]
    lines += [
        f"Mapped roads: {n_map} vehicle-epochs of pc-map whose true position is in a usable tile; there `pc` had a plane in {pc_avail / max(1, n_map):.2f} of them.",
        "",
        "| check | measured | required | holds |",
        "|---|---|---|---|",
        *[f"| {name} | {val:.2f} | {req} | {'yes' if ok else '**no**'} |" for name, val, req, ok in checks],
        "",
    ]
    return use, runs


def experiment_sharpen(work: Path, seeds: dict, lines: list[str], img: Path) -> RoadMap:
    cfg = RoadMapConfig()
    road_map = RoadMap(cfg)
    recs = [
        simulate(work / f"sharpen-{seed}", seed, 300.0, offset_s=600.0 * k)
        for k, seed in enumerate(seeds["sharpen"])
    ]
    points = truth_points(recs, cfg.tile_size_m)
    lines += [
        f"### 2. Sharpening: {len(recs)} runs of 300 s (seeds {', '.join(map(str, seeds['sharpen']))}, 10 min apart), added one after another",
        "",
        "After each run: over the usable tiles, the median number of passes, the median height sigma the map reports and the RMS of its height error at the true road points (where the vehicles drive), the share of tiles whose error is inside 2 sigma, and sigma x sqrt(passes) (constant if sigma follows 1/sqrt(n)).",
        "",
        "| runs | usable tiles | median passes | median sigma (m) | RMS error (m) | inside 2 sigma | sigma x sqrt(passes) |",
        "|---|---|---|---|---|---|---|",
    ]
    ns, sig, rms = [], [], []
    for k, rec in enumerate(recs):
        extend_map(road_map, run_method(rec, "pc"), rec)
        rows = np.array(map_errors(road_map, points))
        n_med = float(np.median(rows[:, 0]))
        ns.append(n_med)
        sig.append(float(np.median(rows[:, 1])))
        rms.append(float(np.sqrt(np.mean(rows[:, 2] ** 2))))
        inside = float(np.mean(np.abs(rows[:, 2]) <= 2 * rows[:, 1]))
        lines.append(
            f"| {k + 1} | {len(rows)} | {n_med:.0f} | {sig[-1]:.3f} | {rms[-1]:.3f} | {inside:.2f} | {sig[-1] * math.sqrt(n_med):.2f} |"
        )
    lines.append("")
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.loglog(ns, sig, "o-", label="median reported sigma")
    ax.loglog(ns, rms, "s-", label="RMS height error vs truth")
    ref = sig[0] * math.sqrt(ns[0]) / np.sqrt(np.array(ns, dtype=float))
    ax.loglog(ns, ref, "k--", label="1/sqrt(n) from the first run")
    ax.set_xlabel("median passes behind a tile")
    ax.set_ylabel("road height (m)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title("Tile height sigma and error as runs are added")
    fig.tight_layout()
    fig.savefig(img, dpi=110)
    plt.close(fig)
    lines += [f"![sigma vs passes]({img.relative_to(DOCS) if img.is_relative_to(DOCS) else img})", ""]
    return road_map


def experiment_reuse(use: Recording, runs: dict[str, MethodRun], road_map: RoadMap, lines: list[str]) -> None:
    """The map of several drives on experiment 1's use drive: what a fleet that keeps driving gets."""
    stats = road_map.stats()
    lines += [
        "### 2b. The sharpened map in use",
        "",
        "The map after the runs of experiment 2 ("
        + ", ".join(f"{k} {v}" for k, v in stats.items())
        + ") on experiment 1's use drive, against the same runs without a map. The use drive's sky overlaps the last sharpening runs' (45-50 min against 40-45 min after the first), its noise, multipath and NLOS are its own seed's.",
        "",
        "| method | H RMSE (m) | V RMSE (m) | plane from map / fitted / none |",
        "|---|---|---|---|",
    ]
    for m in ("non-cp", "pc", "pc-map", "pc-self-map"):
        run = run_method(use, m, road_map=road_map) if m.endswith("-map") else runs[m]
        h, v, _ = pooled_rmse(run, use)
        src = plane_sources(run)
        lines.append(
            f"| {m} | {h:.2f} | {v:.2f} | {src.get('map', 0)} / {src.get('fleet', 0) + src.get('self', 0)} / {src.get('none', 0)} |"
        )
    lines.append("")


def experiment_change(work: Path, seeds: dict, road_map: RoadMap, lines: list[str]) -> None:
    cfg = road_map.config
    base = truth_planes(
        truth_points([open_recording(work / f"sharpen-{s}") for s in seeds["sharpen"]], cfg.tile_size_m),
        cfg.tile_size_m,
    )
    lines += [
        f"### 3. Change: the road between s = {RAISE.s_start_m:.0f} and {RAISE.s_end_m:.0f} m raised by {RAISE.dz_m} m",
        "",
        "The map of experiment 2 is extended by runs over the raised road, one after another, starting an hour after the first sharpening run (a vehicle's evidence counts once, in time order). Affected tiles: those where the run's true road points lie more than 0.25 m above the old road. Per run: the errors of `pc` and `pc-map` on the affected tiles (before the run is added to the map), then how many affected tiles the map has flagged as changed so far, how many other tiles (false changes), and the RMS of the affected tiles' height error at the true road points (after the run is added).",
        "",
        "| run | pc V RMSE there (m) | pc-map V RMSE there (m) | pc-map H RMSE there / pc H (m) | affected tiles flagged | other tiles flagged | RMS tile error (m) |",
        "|---|---|---|---|---|---|---|",
    ]
    changes_before = {k: t.changes for k, t in road_map.tiles.items()}
    for k, seed in enumerate(seeds["change"]):
        # after every sharpening run: a vehicle's evidence counts once, in time order (mapped_until)
        offset = CHANGE_OFFSET_S + 600.0 * k
        rec = simulate(work / f"change-{seed}-{offset:.0f}", seed, 300.0, offset_s=offset, raises=(RAISE,))
        points = truth_points([rec], cfg.tile_size_m)
        affected = {key for key, pts in points.items() if key in base and rise_at(base[key], pts) > 0.25}

        def there(vid: str, t, rec=rec, affected=affected) -> bool:
            p = rec.truth_at(vid).get(t)
            h = rec.manifest.vehicle(vid).antenna_height_m
            return (
                p is not None and tile_of_ecef(project_to_road(np.asarray(p), h), cfg.tile_size_m) in affected
            )

        pc = run_method(rec, "pc")
        pcm = run_method(rec, "pc-map", road_map=road_map)
        h_pc, v_pc, _ = pooled_rmse(pc, rec, there)
        h_pm, v_pm, _ = pooled_rmse(pcm, rec, there)
        extend_map(road_map, pc, rec)
        changed = {key for key, tile in road_map.tiles.items() if tile.changes > changes_before.get(key, 0)}
        flagged = len(changed & affected)
        errs = [e for _, _, e in map_errors(road_map, {key: points[key] for key in affected})]
        rms = float(np.sqrt(np.mean(np.square(errs)))) if errs else math.nan
        lines.append(
            f"| {k + 1} (seed {seed}) | {v_pc:.2f} | {v_pm:.2f} | {h_pm:.2f} / {h_pc:.2f} | {flagged} of {len(affected)} | {len(changed - affected)} | {rms:.2f} |"
        )
    lines.append("")


def report(training: bool = False, work: Path | None = None) -> str:
    """The road-map section of docs/results.md (`training`: on the seeds the defaults were chosen on)."""
    which = "training" if training else "report"
    seeds = SEEDS[which]
    work = work or Path(tempfile.mkdtemp(prefix="coplane-roadmap-"))
    lines = [
        "## Road-surface map (issue 14)",
        "",
        f"Regenerated by `.venv/bin/python bench/roadmap_acceptance.py{' --training' if training else ''}` on {time.strftime('%Y-%m-%d')} (simulated {SCENARIO}, 4 vehicles, DGNSS base, UWB). Design: docs/roadmap.md. Seeds: {which} set ({'the map defaults were checked on these' if training else 'none of them was used to choose a default; the defaults (RoadMapConfig.max_use_sigma_m) were chosen on the --training seeds 111/112'}).",
        "",
    ]
    t0 = time.perf_counter()
    use, runs = experiment_use(work, seeds, lines)
    from roadmap_build_length import experiment_build_length, experiment_standalone  # this one is full

    experiment_build_length(work, seeds["build"], seeds["length"], use, runs, lines)
    experiment_standalone(work, seeds["build"], lines)
    # the training run prints only: its figure stays in the work folder
    img = work / "roadmap-sharpening-training.png" if training else DOCS / "img" / "roadmap-sharpening.png"
    road_map = experiment_sharpen(work, seeds, lines, img)
    experiment_reuse(use, runs, road_map, lines)
    experiment_change(work, seeds, road_map, lines)
    lines.append(f"Total run time {time.perf_counter() - t0:.0f} s.")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--training", action="store_true", help="run on the seeds the defaults were checked on")
    ap.add_argument("--work", type=Path, default=None, help="folder for the simulated recordings (kept)")
    args = ap.parse_args()
    text = report(args.training, args.work)
    print(text)
    if not args.training:  # the report seeds: docs/results.md's road-map section
        from make_results import assemble, write_section

        write_section("road-map", text)
        assemble()


if __name__ == "__main__":
    main()
