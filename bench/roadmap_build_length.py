"""Experiment 1b of bench/roadmap_acceptance.py: which single drive a map is built from, and how
long it is.

A map built from one drive carries that drive's errors that are common to the whole fleet: with
DGNSS, the base station's own code multipath (a geodetic antenna: 0.1-1 m, correlated over
`tau_s` = 300 s in the simulator, coplane.sim.errors.base_receiver_params) goes into every
vehicle's corrections, so every tile of a 10-minute drive is offset by about the same amount, and
the fleet cannot see it. Only a longer drive (or more drives, experiment 2) averages it out. Maps
from single drives (experiment 1's, two other seeds of 10 minutes, and the first of those for 20
and 40 minutes) are used on experiment 1's use drive. Nothing here chooses a default.

Experiment 1c: the same build drive without its base station, and what the map's trust filter keeps
of it.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
from roadmap_acceptance import map_errors, pooled_rmse, simulate, truth_points

from coplane.evaluate.map_build import extend_map
from coplane.evaluate.runner import MethodRun, run_method
from coplane.methods import get_method
from coplane.recording.reader import Recording
from coplane.roadmap import RoadMap, RoadMapConfig

LENGTHS_S = (600.0, 1200.0, 2400.0)  # for the first seed; the others are 10-minute drives


def _drive_up_error(run: MethodRun, rec: Recording) -> tuple[float, float]:
    """Mean and RMS of the drive's own vertical error (pc, every vehicle-epoch)."""
    ups = []
    for v in rec.manifest.vehicles:
        truth = rec.truth_at(v.id)
        for t, p in run.positions[v.id].items():
            if t in truth:
                q = np.asarray(truth[t], dtype=float)
                ups.append(float((np.asarray(p) - q) @ (q / np.linalg.norm(q))))
    u = np.asarray(ups)
    return float(np.mean(u)), float(np.sqrt(np.mean(u**2)))


def experiment_build_length(
    work: Path,
    build_seed: int,
    seeds: tuple[int, ...],
    use: Recording,
    runs: dict[str, MethodRun],
    lines: list[str],
) -> None:
    """Maps from one drive each, on the use drive of experiment 1: experiment 1's own build drive
    (`build_seed`, 10 min), each of `seeds` for 10 min, and the first of them for 20 and 40 min."""
    points = truth_points([use], RoadMapConfig().tile_size_m)
    _, pc_v, _ = pooled_rmse(runs["pc"], use)
    _, noncp_v, _ = pooled_rmse(runs["non-cp"], use)
    lines += [
        "### 1b. One build drive: which drive, and how long (used on experiment 1's use drive)",
        "",
        "A map from one drive carries the errors that drive's whole fleet shared (with DGNSS, e.g. the base station's code multipath, correlated over minutes, which goes into every vehicle's corrections): the fleet cannot see them, so neither can the map's sigma. Per build drive: its own vertical error (`pc`, mean and RMS), the map's signed mean height error over the usable tiles at the use drive's true road points and its RMS, the median sigma the map reports, then the map methods on the use drive. The longer drives extend the first seed's; all end before the use drive begins (45 min after the build start).",
        "",
        f"| build drive | its pc V mean / RMS (m) | usable tiles | map mean error (m) | map RMS error (m) | median sigma (m) | pc-map V (m) | pc-map V / pc V ({pc_v:.2f}) | pc-self-map V / non-cp V ({noncp_v:.2f}) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    drives = [(build_seed, 600.0, f"build-{build_seed}", " (experiment 1's)")]
    drives += [(s, 600.0, f"length-{s}-600", "") for s in seeds]
    drives += [(seeds[0], length, f"length-{seeds[0]}-{length:.0f}", "") for length in LENGTHS_S[1:]]
    for seed, length, folder, note in drives:
        build = simulate(work / folder, seed, length)
        road_map = RoadMap(RoadMapConfig())
        built = run_method(build, "pc")
        extend_map(road_map, built, build)
        mean_up, rms_up = _drive_up_error(built, build)
        rows = np.array(map_errors(road_map, points))
        _, v_map, _ = pooled_rmse(run_method(use, "pc-map", road_map=road_map), use)
        _, v_self, _ = pooled_rmse(run_method(use, "pc-self-map", road_map=road_map), use)
        lines.append(
            f"| seed {seed}, {length / 60:.0f} min{note} | {mean_up:+.2f} / {rms_up:.2f} | {len(rows)}"
            f" | {np.mean(rows[:, 2]):+.2f} | {np.sqrt(np.mean(rows[:, 2] ** 2)):.2f} | {np.median(rows[:, 1]):.2f}"
            f" | {v_map:.2f} | {v_map / pc_v:.2f} | {v_self / noncp_v:.2f} |"
        )
    lines.append("")


def _median_sigma_up(run: MethodRun) -> float:
    """Median reported vertical 1-sigma over every vehicle-epoch of a run."""
    s = []
    for vid, covs in run.covariances.items():
        for t, c in covs.items():
            p = np.asarray(run.positions[vid][t], dtype=float)
            up = p / np.linalg.norm(p)
            s.append(float(np.sqrt(up @ np.asarray(c, dtype=float).reshape(3, 3) @ up)))
    return float(np.median(s)) if s else float("nan")


def experiment_standalone(work: Path, build_seed: int, lines: list[str]) -> None:
    """Experiment 1's build drive solved without its base station: what the map's trust filter
    keeps, with the atmosphere's residual in the reported covariance (the default) and without."""
    build = simulate(work / f"build-{build_seed}", build_seed, 600.0)
    pc = get_method("pc")
    assert pc.fgo is not None
    variants = {
        "default (the atmosphere's residual in the covariance)": pc,
        "`covariance_common_scale = 0` (the default until 2026-11-29)": replace(
            pc, fgo=replace(pc.fgo, covariance_common_scale=0.0)
        ),
    }
    lines += [
        f"### 1c. Without a base station: experiment 1's build drive (seed {build_seed}, 10 min) solved standalone",
        "",
        f"What the map's trust filter (`max_sigma_up_m` {RoadMapConfig().max_sigma_up_m:g} m, `max_sigma_h_m` "
        f"{RoadMapConfig().max_sigma_h_m:g} m) keeps of a standalone `pc` drive. Without a base the reported "
        "covariance carries the broadcast atmosphere's residual (docs/fgo.md), an error every vehicle of the "
        "drive shares for tens of minutes; the map adds passes as independent evidence, so it must not "
        "take that drive's heights as sharper than that error (docs/roadmap.md, 'Without a base station').",
        "",
        "Per setting: the drive's median reported vertical sigma, what the build kept, and the map against "
        "the drive's own true road points (usable tiles: signed mean and RMS height error, median sigma).",
        "",
        "| covariance | median vertical sigma (m) | solved vehicle-epochs | skipped samples | passes | usable tiles | map mean / RMS error (m) | map median sigma (m) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    points = truth_points([build], RoadMapConfig().tile_size_m)
    for name, spec in variants.items():
        run = run_method(build, spec, dgnss=False)
        road_map = RoadMap(RoadMapConfig())
        ext = extend_map(road_map, run, build)
        skipped = ", ".join(f"{k} {v}" for k, v in sorted(ext.skipped.items())) or "0"
        rows = np.array(map_errors(road_map, points)).reshape(-1, 3)
        err = (
            f"{np.mean(rows[:, 2]):+.2f} / {np.sqrt(np.mean(rows[:, 2] ** 2)):.2f} | {np.median(rows[:, 1]):.2f}"
            if len(rows)
            else "- | -"
        )
        lines.append(
            f"| {name} | {_median_sigma_up(run):.2f} | {ext.samples} | {skipped} | {ext.passes}"
            f" | {road_map.stats()['usable_tiles']} | {err} |"
        )
    lines.append("")
