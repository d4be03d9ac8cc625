"""SPP over a whole recording (`coplane spp`): per vehicle and epoch, standalone or DGNSS."""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np
from tqdm import tqdm

from coplane.gnss.epoch_solver import EpochResult, EpochSolverOptions, base_corrections, solve_epoch
from coplane.gtime import GpsTime
from coplane.recording.reader import Recording


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
        rec.manifest.vehicle(vid)  # KeyError with a clear message for unknown ids
    base = rec.manifest.base
    if dgnss and base is None:
        raise ValueError(f"recording {rec.manifest.name!r} has no [base] station: DGNSS is not possible")
    runs = {vid: VehicleSppRun(vid) for vid in ids}
    last: dict[str, np.ndarray] = {}
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
            res = solve_epoch(ep, rec.nav, corr, opt, last.get(vid))
            runs[vid].results[fe.time] = res
            if res.spp.ok:
                last[vid] = res.spp.position
            else:
                runs[vid].no_solution[(res.spp.reason or "?").split(":")[0]] += 1
    return runs
