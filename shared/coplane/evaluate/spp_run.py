"""SPP over a whole recording (`coplane spp`): per vehicle and epoch, standalone or DGNSS.

`run_spp` solves in memory; `spp_to_pos` is the command's whole job (solve, write one RTKLIB .pos
per vehicle, score against truth) and returns an `SppReport` for the caller to render.
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from tqdm import tqdm

from coplane.errors import ConfigError
from coplane.evaluate.metrics import AccuracyStats, accuracy
from coplane.evaluate.solution_files import write_pos
from coplane.evaluate.truth import Truth, TruthChoice, apply_truth
from coplane.gnss.epoch_solver import (
    EpochResult,
    EpochSolverOptions,
    ReceiverMemory,
    base_corrections,
    solve_next,
)
from coplane.gtime import GpsTime
from coplane.recording.health import InputHealth, input_health
from coplane.recording.reader import Recording, open_recording
from coplane.recording.trajectories import Q_DGPS, Q_SINGLE, PosRecord

log = logging.getLogger(__name__)


@dataclass
class VehicleSppRun:
    vehicle: str
    results: dict[GpsTime, EpochResult] = field(default_factory=dict)  # keyed by nominal epoch time
    no_solution: Counter[str] = field(default_factory=Counter)

    @property
    def n_epochs(self) -> int:
        return len(self.results)

    def fixes(self) -> dict[GpsTime, np.ndarray]:
        return {t: r.spp.position for t, r in self.results.items() if r.spp.ok}


def run_spp(
    rec: Recording,
    vehicles: Iterable[str] | None = None,
    dgnss: bool = False,
    options: EpochSolverOptions | None = None,
    progress: bool = False,
) -> dict[str, VehicleSppRun]:
    """Solve every epoch of the chosen vehicles. DGNSS needs the recording's [base]."""
    opt = options or EpochSolverOptions()
    ids = list(vehicles) if vehicles is not None else [v.id for v in rec.manifest.vehicles]
    for vid in ids:
        try:
            rec.manifest.vehicle(vid)
        except KeyError as exc:  # the user named a vehicle the recording lacks
            raise ConfigError(str(exc)) from exc
    base = rec.manifest.base
    if dgnss and base is None:
        raise ConfigError(f"recording {rec.manifest.name!r} has no [base] station: DGNSS is not possible")
    runs = {vid: VehicleSppRun(vid) for vid in ids}
    memory = {vid: ReceiverMemory() for vid in ids}
    epochs = rec.fleet_epochs()
    for fe in tqdm(epochs, desc="spp", unit="epoch", disable=not progress):
        corr = None
        if dgnss:
            if fe.base is None:
                for vid in ids:
                    if vid in fe.vehicles:
                        runs[vid].no_solution["no base epoch"] += 1
                continue
            assert base is not None
            corr = base_corrections(fe.base, np.asarray(base.position_ecef_m), rec.nav, opt)
        for vid in ids:
            ep = fe.vehicles.get(vid)
            if ep is None:
                continue
            res = solve_next(ep, rec.nav, memory[vid], corr, opt)
            runs[vid].results[fe.time] = res
            if not res.spp.ok:
                runs[vid].no_solution[(res.spp.reason or "?").split(":")[0]] += 1
    return runs


@dataclass(frozen=True)
class VehicleSppSummary:
    """One vehicle's row of `coplane spp`: where its .pos went, availability and accuracy."""

    vehicle: str
    pos_path: Path
    n_epochs: int
    n_fixes: int
    accuracy: AccuracyStats | None  # None when the recording has no truth for the vehicle
    no_solution: Counter[str]  # epochs without a fix, by reason

    @property
    def availability_pct(self) -> float:
        return 100.0 * self.n_fixes / self.n_epochs if self.n_epochs else 0.0


@dataclass(frozen=True)
class SppReport:
    """What `coplane spp` did, for the caller to render."""

    recording: str  # the recording's name
    dgnss: bool
    vehicles: list[VehicleSppSummary]
    problems: Counter[str]  # input problems found while reading, by kind
    health: InputHealth  # records kept against problems, for --strict
    truth_note: str = ""  # what the accuracy was measured against, when not the recording's truth

    @property
    def problems_total(self) -> int:
        return sum(self.problems.values())


def spp_to_pos(
    recording: Path,
    out: Path,
    vehicles: Iterable[str] | None = None,
    dgnss: bool = False,
    fde: bool = True,
    progress: bool = False,
    truth: Truth | TruthChoice = "recording",
) -> SppReport:
    """SPP of each vehicle; `out` is the .pos file, or with several vehicles `<stem>_<id>.pos` each.

    `fde` turns RAIM fault detection and exclusion on; `truth`: what the accuracy is measured
    against (`evaluate.truth`). Raises a `CoplaneError` for a recording that cannot be used, an
    unknown vehicle, DGNSS without a base station, or a truth that cannot be made or read.
    """
    rec = open_recording(recording)
    truth_note = apply_truth(rec, truth)
    opts = EpochSolverOptions()
    opts = replace(opts, spp=replace(opts.spp, raim="fde" if fde else "off"))
    runs = run_spp(rec, vehicles, dgnss=dgnss, options=opts, progress=progress)
    summaries = []
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
        log.info("wrote %s", target)
        ref = rec.truth_at(vid)
        st = accuracy(fixes, {t: np.asarray(p) for t, p in ref.items()}) if ref else None
        summaries.append(VehicleSppSummary(vid, target, run.n_epochs, len(fixes), st, run.no_solution))
    return SppReport(
        rec.manifest.name, dgnss, summaries, Counter(rec.problems.counts), input_health(rec), truth_note
    )
