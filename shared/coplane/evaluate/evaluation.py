"""Run several methods and interruption rates on one recording and write tables, CSVs and figures.

The result carries everything `coplane eval` shows (stats, notes, timings); nothing here prints.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from coplane.errors import ConfigError
from coplane.evaluate.front_ends import FrontEndMemo
from coplane.evaluate.metrics import AccuracyStats, PooledStats
from coplane.evaluate.plots import plot_cdfs, plot_error_vs_time, plot_plane_map, plot_rmse_vs_interruption
from coplane.evaluate.report import (
    environment_stats,
    run_stats,
    write_environment_tables,
    write_exclusions,
    write_solutions,
    write_tables,
)
from coplane.evaluate.rtklib_row import RTKLIB_METHOD, evaluation_row
from coplane.evaluate.runner import MethodRun, require_map, run_method
from coplane.evaluate.truth import Truth, TruthChoice, apply_truth, missing_truth_note
from coplane.methods import MethodSpec, get_method
from coplane.recording.reader import Recording

log = logging.getLogger(__name__)

if TYPE_CHECKING:
    from coplane.roadmap import RoadMap


@dataclass
class Evaluation:
    runs: list[MethodRun] = field(default_factory=list)
    stats: dict[str, dict[str, AccuracyStats]] = field(default_factory=dict)  # label -> vehicle -> stats
    # label -> "all" / environment -> errors pooled over vehicles (p99 and max included)
    by_environment: dict[str, dict[str, PooledStats]] = field(default_factory=dict)
    figures: list[Path] = field(default_factory=list)
    notes: dict[str, str] = field(default_factory=dict)  # method -> remark (e.g. the rtklib row skipped)
    recording: str = ""  # the recording's name, for titles
    # the vehicles to tabulate: those asked for, else all that have truth
    shown: list[str] = field(default_factory=list)


def _check_map(specs: Sequence[MethodSpec | None], road_map: RoadMap | None) -> None:
    """Map methods without a map, or a map no method reads, stop the run before anything runs:
    the first would fail only after the methods before it had run, the second would write tables
    that silently ignore the map the user meant to evaluate."""
    methods = [s for s in specs if s is not None]
    require_map(methods, road_map)
    if road_map is not None and not any(s.plane_map for s in methods):
        raise ConfigError(
            "a road-surface map was given, but none of the methods reads one: add pc-map or"
            " pc-self-map to the methods, or leave the map out"
        )


def evaluate(
    rec: Recording,
    methods: Sequence[str],
    rates: Sequence[float] = (0.0,),
    out_dir: Path | None = None,
    seed: int = 0,
    vehicles: Sequence[str] | None = None,
    dgnss: bool | None = None,
    progress: bool = False,
    jobs: int | None = None,
    road_map: RoadMap | None = None,
    fgo: dict[str, object] | None = None,
    truth: Truth | TruthChoice = "recording",
) -> Evaluation:
    """Every method at rate 0; methods that use ranging also at each rate > 0 (paper 5.3). `fgo`:
    factor-graph settings changed for every FGO method (`--fgo`; the baselines have none).
    `truth`: what the errors are measured against (`evaluate.truth`): "rtk" makes every
    vehicle's truth RTKLIB's RTK against the base, where it gives one, for recordings with carrier
    phase but no surveyed trajectory; a TruthChoice's files replace the named vehicles' truth."""
    # validate names (and settings) first
    if not methods:
        raise ConfigError("no method to run: name at least one (e.g. --methods non-cp,pc)")
    methods = list(dict.fromkeys(methods))  # one run per method, however often it is named
    specs = [None if m == RTKLIB_METHOD else get_method(m, fgo=fgo) for m in methods]
    _check_map(specs, road_map)
    for vid in vehicles or ():
        rec.manifest.vehicle(vid)  # an unknown one is named before anything runs
    if dgnss and rec.manifest.base is None and any(s is not None for s in specs):
        # the runner would refuse too, but only after the methods before it had run
        raise ConfigError(f"recording {rec.manifest.name!r} has no [base]: cannot run with DGNSS")
    ev = Evaluation(recording=rec.manifest.name)
    notes = [n for n in (apply_truth(rec, truth), missing_truth_note(rec)) if n]
    if notes:
        ev.notes["truth"] = "; ".join(notes)
        log.info("%s", ev.notes["truth"])
    if fgo:  # in accuracy.json too: these are not the methods' defaults
        changed = ", ".join(f"{k}={v}" for k, v in fgo.items())
        ev.notes["fgo"] = f"factor-graph settings changed for every FGO method: {changed}"
    # in one process every run after the first skips the GNSS front ends (a quarter to two fifths
    # less time); with vehicle workers they already run beside the fusion step, and a memo measured
    # slower there (docs/performance.md)
    memo = FrontEndMemo() if jobs == 1 else None
    for spec in specs:
        if spec is None:  # the RTKLIB reference row: RINEX straight into RTKLIB, optional pyrtklib
            rtk_run, ev.notes[RTKLIB_METHOD] = evaluation_row(rec, dgnss)
            log.info("%s", ev.notes[RTKLIB_METHOD])
            if rtk_run is not None:
                ev.runs.append(rtk_run)
                ev.stats[rtk_run.label] = run_stats(rtk_run, rec)
                ev.by_environment[rtk_run.label] = environment_stats(rtk_run, rec)
                if out_dir is not None:
                    write_solutions(rtk_run, out_dir)
            continue
        for rate in sorted(set(rates) | {0.0}):
            if rate > 0 and not spec.uses_ranging:
                continue
            run = run_method(
                rec,
                spec,
                interruption=rate,
                seed=seed,
                dgnss=dgnss,
                progress=progress,
                jobs=jobs,
                road_map=road_map,
                front_ends=memo,
            )
            ev.runs.append(run)
            ev.stats[run.label] = run_stats(run, rec)
            ev.by_environment[run.label] = environment_stats(run, rec)
            if out_dir is not None:
                write_solutions(run, out_dir)
    if out_dir is not None:
        shown = list(vehicles or [v.id for v in rec.manifest.vehicles])
        write_tables(
            ev.stats,
            shown,
            out_dir,
            extra={
                "notes": ev.notes,
                "timing": {
                    r.label: {
                        "wall_s": r.wall_time_s,
                        "epochs": r.n_epochs,
                        "solve_median_s": float(np.median(r.solve_times_s)) if r.solve_times_s else None,
                    }
                    for r in ev.runs
                },
            },
        )
        write_environment_tables(ev.by_environment, out_dir)
        write_exclusions([r for r in ev.runs if r.interruption == 0], out_dir)
        ev.figures = write_figures(ev, rec, shown, out_dir)
    ev.shown = list(vehicles or [v.id for v in rec.manifest.vehicles if rec.truth_at(v.id)])
    return ev


def write_figures(ev: Evaluation, rec: Recording, vehicles: Sequence[str], out_dir: Path) -> list[Path]:
    figs: list[Path] = []
    base_runs = [r for r in ev.runs if r.interruption == 0]
    truth_all = {
        v.id: {t: np.asarray(p) for t, p in rec.truth_at(v.id).items()} for v in rec.manifest.vehicles
    }
    for vid in vehicles:
        truth = truth_all.get(vid)
        if not truth:
            continue
        figs += plot_cdfs(base_runs, truth, vid, out_dir)
        worst = max((r.interruption for r in ev.runs), default=0.0)
        figs.append(
            plot_error_vs_time(
                [r for r in ev.runs if r.interruption == worst and r.method in ("pc", "mci")] or base_runs,
                truth,
                vid,
                out_dir,
            )
        )
        by_method: dict[str, dict[float, AccuracyStats]] = {}
        for r in ev.runs:
            if vid in ev.stats[r.label]:
                by_method.setdefault(r.method, {})[r.interruption] = ev.stats[r.label][vid]
        multi = {m: d for m, d in by_method.items() if len(d) > 1}
        if multi:
            figs.append(plot_rmse_vs_interruption(multi, vid, out_dir))
    plane_run = next((r for r in base_runs if r.planes), None)
    if plane_run is not None:
        figs.append(plot_plane_map(plane_run, truth_all, out_dir))
    return figs
