"""`coplane eval`'s engine: replay a recording in-process through VehicleStep and FusionStep.

Lockstep semantics, exactly as over the bus: at nominal epoch t every live vehicle builds its node
message from positions solved up to t-1 (paper eq. 2), the fusion step solves t, and every vehicle
ingests the solution before t+1.
"""

from __future__ import annotations

import time as _time
from collections import defaultdict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from tqdm import tqdm

from coplane.errors import ConfigError
from coplane.evaluate.front_ends import FrontEndMemo, Fronts
from coplane.evaluate.vehicle_workers import VehicleWorkers, default_jobs, split_vehicles
from coplane.gnss.dgnss import DgnssCorrections
from coplane.gnss.epoch_solver import EpochResult, EpochSolverOptions
from coplane.gtime import GpsTime
from coplane.messages import NodeMessage, PlaneReport, PlaneSummary, SolutionMessage
from coplane.methods import MethodSpec
from coplane.plane.config import PlaneConfig
from coplane.recording.reader import Recording
from coplane.replay import BaseCorrections, replay_setup, uwb_for_vehicle, vehicle_schedule
from coplane.steps import VehicleStep, gps_time
from coplane.typing import AnyArray as Vec

if TYPE_CHECKING:
    from coplane.roadmap import RoadMap


@dataclass
class MethodRun:
    """Everything one method produced on one recording (per vehicle, per nominal epoch)."""

    method: str
    interruption: float
    positions: dict[str, dict[GpsTime, Vec]] = field(default_factory=lambda: defaultdict(dict))
    covariances: dict[str, dict[GpsTime, Vec]] = field(default_factory=lambda: defaultdict(dict))
    planes: dict[str, dict[GpsTime, PlaneReport]] = field(default_factory=lambda: defaultdict(dict))
    # what the solution said of each vehicle's plane (status, reason, source): all a run over the
    # bus has of it, since `coplane fleet` collects solutions and not the agents' node messages
    plane_summaries: dict[str, dict[GpsTime, PlaneSummary]] = field(default_factory=lambda: defaultdict(dict))
    plane_used: dict[str, dict[GpsTime, bool]] = field(default_factory=lambda: defaultdict(dict))
    ranges_used: dict[str, dict[GpsTime, int]] = field(default_factory=lambda: defaultdict(dict))
    gnss_fix: dict[str, dict[GpsTime, bool]] = field(default_factory=lambda: defaultdict(dict))
    # the satellites the vehicle's SPP used, and the pseudoranges the estimator kept of them
    satellites: dict[str, dict[GpsTime, int]] = field(default_factory=lambda: defaultdict(dict))
    pseudoranges_used: dict[str, dict[GpsTime, int]] = field(default_factory=lambda: defaultdict(dict))
    excluded: dict[str, dict[GpsTime, tuple[str, ...]]] = field(default_factory=lambda: defaultdict(dict))
    # the agent's RAIM exclusions and its fix's HDOP / VDOP (None: no fix), per vehicle and epoch
    raim_excluded: dict[str, dict[GpsTime, tuple[str, ...]]] = field(
        default_factory=lambda: defaultdict(dict)
    )
    dops: dict[str, dict[GpsTime, tuple[float | None, float | None]]] = field(
        default_factory=lambda: defaultdict(dict)
    )
    # the age of the DGNSS corrections the agent's fix used (None: standalone), per vehicle and epoch
    dgnss_age_s: dict[str, dict[GpsTime, float | None]] = field(default_factory=lambda: defaultdict(dict))
    solve_times_s: list[float] = field(default_factory=list)
    wall_time_s: float = 0.0
    n_epochs: int = 0

    @property
    def label(self) -> str:
        return self.method if self.interruption <= 0 else f"{self.method}@r{round(self.interruption * 100)}"


def lockstep_schedule(rec: Recording, vehicles: list[str]) -> list[tuple[GpsTime, dict[str, Any]]]:
    """[(t, {vehicle: ObsEpoch | None for live vehicles})] over the union of the vehicles' spans."""
    dt = rec.manifest.interval_s
    per: dict[GpsTime, dict[str, Any]] = defaultdict(dict)
    for vid in vehicles:
        for t, ep in vehicle_schedule(rec.vehicle_epochs(vid), dt):
            per[t][vid] = ep
    return sorted(per.items(), key=lambda kv: kv[0])


def require_map(specs: Sequence[MethodSpec], road_map: RoadMap | None) -> None:
    """The map methods among `specs` cannot run without a road-surface map: say so, naming them."""
    names = [s.name for s in specs if s.plane_map]
    if names and road_map is None:
        raise ConfigError(
            f"{', '.join(names)} {'takes its' if len(names) == 1 else 'take their'} planes from a"
            " road-surface map: give one (--map MAP; `coplane map build` makes it)"
        )


def run_method(
    rec: Recording,
    method: MethodSpec | str,
    interruption: float = 0.0,
    seed: int = 0,
    dgnss: bool | None = None,
    vehicles: list[str] | None = None,
    progress: bool = False,
    on_solution: Any = None,
    plane_config: PlaneConfig | None = None,
    jobs: int | None = None,
    road_map: RoadMap | None = None,
    front_end: EpochSolverOptions | None = None,
    front_ends: FrontEndMemo | None = None,
) -> MethodRun:
    """Run one method over the recording. DGNSS is used when the recording has a base (default).

    `jobs` processes share the work (None: one per core, at most one per vehicle plus one for the
    fusion step; 1: all in this process). The result is the same bits for any `jobs`
    (evaluate.vehicle_workers). `front_ends`: the GNSS front ends remembered for the next runs on
    `rec` (or taken from the earlier ones), for several methods on one recording; same bits (the
    run's `wall_time_s` then leaves out the front ends an earlier run computed).
    """
    if jobs is not None and jobs < 1:
        raise ConfigError(f"jobs must be >= 1, got {jobs}")
    setup = replay_setup(
        rec.manifest,
        method,
        seed=seed,
        interruption=interruption,
        dgnss=dgnss,
        plane_config=plane_config,
        road_map=road_map,
        front_end=front_end,
    )
    require_map([setup.method], road_map)
    ids = vehicles or [v.id for v in rec.manifest.vehicles]
    steps = {vid: setup.vehicle_step(rec, vid) for vid in ids}
    fusion = setup.fusion_step()
    schedule = lockstep_schedule(rec, ids)
    uwb_rows = rec.uwb()
    uwb = {
        vid: uwb_for_vehicle(
            uwb_rows, vid, (t for t, live in schedule if vid in live), rec.manifest.interval_s
        )
        for vid in ids
    }
    run = MethodRun(setup.method.name, interruption)
    base = (
        front_ends.base(rec, setup.use_dgnss)
        if front_ends is not None
        else BaseCorrections.of(rec, setup.use_dgnss)
    )
    replay = _Replay(schedule, uwb, base)
    n_jobs = default_jobs(len(ids)) if jobs is None else jobs
    workers_on = n_jobs > 1 and VehicleWorkers.available()
    # With workers this process runs the fusion step (as the server does on the bus) and a smaller
    # share of the vehicles: a worker's GNSS front ends run ahead while the fusion step solves, so
    # in the critical path a worker's vehicle costs about half of one of this process's.
    n_workers = n_jobs - 1 if workers_on else 0
    n_own = len(ids) // (2 * n_workers + 1) if workers_on else len(ids)
    own = {vid: steps[vid] for vid in ids[:n_own]}
    groups = split_vehicles(ids[n_own:], n_workers) if workers_on else []
    t_start = _time.perf_counter()
    if front_ends is not None:  # before the workers fork, so that they have them too
        replay.known = front_ends.fronts(rec, steps, schedule, setup.use_dgnss, replay.corrections)
    with VehicleWorkers([{vid: steps[vid] for vid in g} for g in groups], replay, len(schedule)) as workers:
        sol: SolutionMessage | None = None
        for k, (t, _) in enumerate(
            tqdm(schedule, desc=run.label, unit="epoch", disable=not progress, leave=False)
        ):
            workers.submit(k, sol)
            if sol is not None:
                for s in own.values():
                    s.ingest(sol)
            msgs = replay.messages(own, k) | workers.collect()
            msgs = dict(sorted(msgs.items()))
            sol = fusion.solve(t, msgs)
            record_solution(run, sol, msgs)
            if on_solution is not None:
                on_solution(sol, msgs)
    run.wall_time_s = _time.perf_counter() - t_start
    run.n_epochs = len(schedule)
    return run


@dataclass
class _Replay:
    """The vehicles' side of a lockstep replay, for `VehicleWorkers` and for this process alike."""

    schedule: list[tuple[GpsTime, dict[str, Any]]]
    uwb: Mapping[str, Mapping[GpsTime, Any]]
    base: BaseCorrections
    known: Fronts = field(default_factory=dict)  # front ends computed before the run (`FrontEndMemo`)
    _fronts: Fronts = field(default_factory=dict)

    def corrections(self, k: int) -> DgnssCorrections | None:
        """DGNSS corrections of epoch k (each process computes them itself: same bits)."""
        return self.base.at(self.schedule[k][0])

    def ahead(self, steps: Mapping[str, VehicleStep], k: int) -> None:
        t, live = self.schedule[k]
        for vid, ep in sorted(live.items()):
            if vid in steps and (k, vid) not in self.known:
                self._fronts[(k, vid)] = steps[vid].front_end(t, ep, self.corrections(k))

    def messages(self, steps: Mapping[str, VehicleStep], k: int) -> dict[str, NodeMessage]:
        t, live = self.schedule[k]
        corr = self.corrections(k) if any(vid in steps for vid in live) else None
        return {
            vid: steps[vid].process(t, ep, corr, self.uwb[vid].get(t, ()), self._front(k, vid))
            for vid, ep in sorted(live.items())
            if vid in steps
        }

    def _front(self, k: int, vid: str) -> EpochResult | None:
        """Vehicle `vid`'s front end of epoch k if it was computed ahead (else `process` runs it)."""
        front = self._fronts.pop((k, vid), None)
        return front if front is not None else self.known.get((k, vid))


def record_solution(run: MethodRun, sol: SolutionMessage, msgs: dict[str, NodeMessage]) -> None:
    t = gps_time(sol.epoch)
    run.solve_times_s.append(sol.solve_time_s)
    for m in msgs.values():
        if m.plane is not None:
            run.planes[m.vehicle_id][t] = m.plane
    for v in sol.vehicles:
        run.positions[v.vehicle_id][t] = np.array(v.position_ecef_m)
        if v.covariance_m2 is not None:
            run.covariances[v.vehicle_id][t] = np.array(v.covariance_m2).reshape(3, 3)
        run.plane_used[v.vehicle_id][t] = v.plane_used
        if v.plane is not None:
            run.plane_summaries[v.vehicle_id][t] = v.plane
        run.ranges_used[v.vehicle_id][t] = v.n_ranges
        run.gnss_fix[v.vehicle_id][t] = v.has_gnss_fix
        run.satellites[v.vehicle_id][t] = v.n_satellites
        run.pseudoranges_used[v.vehicle_id][t] = v.n_pseudoranges
        run.excluded[v.vehicle_id][t] = tuple(v.excluded_satellites)
        run.raim_excluded[v.vehicle_id][t] = tuple(v.raim_excluded)
        run.dops[v.vehicle_id][t] = (v.hdop, v.vdop)
        run.dgnss_age_s[v.vehicle_id][t] = v.dgnss_age_s
