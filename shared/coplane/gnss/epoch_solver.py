"""One receiver epoch end to end: satellite states, optional DGNSS, SPP with FDE, Doppler velocity.

This is what a vehicle does every epoch before it builds its node message; `coplane spp` and the
per-vehicle step both call it, so there is one definition of "the SPP of a vehicle".
"""

from __future__ import annotations

import itertools
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

from coplane.gnss.dgnss import DgnssCorrections, DgnssOptions, dgnss_corrections
from coplane.gnss.doppler import DopplerOptions, DopplerVelocity, DriftPrior, solve_doppler_velocity
from coplane.gnss.measurements import PreparedEpoch, prepare_epoch
from coplane.gnss.sat_models import SatModels
from coplane.gnss.spp import SppOptions, SppSolution, solve_spp
from coplane.gnss.standstill import DopplerNoise
from coplane.recording.model import NavData, ObsEpoch
from coplane.typing import Vec


@dataclass(frozen=True)
class EpochSolverOptions:
    systems: tuple[str, ...] = ("G", "C")
    spp: SppOptions = field(default_factory=SppOptions)
    doppler: DopplerOptions = field(default_factory=DopplerOptions)
    dgnss: DgnssOptions = field(default_factory=DgnssOptions)


@dataclass
class EpochResult:
    prepared: PreparedEpoch
    spp: SppSolution
    velocity: DopplerVelocity | None
    corrections: DgnssCorrections | None


def base_corrections(
    base_epoch: ObsEpoch, base_position: Vec, nav: NavData, options: EpochSolverOptions | None = None
) -> DgnssCorrections:
    opt = options or EpochSolverOptions()
    return dgnss_corrections(prepare_epoch(base_epoch, nav, opt.systems), base_position, opt.dgnss)


def solve_epoch(
    epoch: ObsEpoch,
    nav: NavData,
    corrections: DgnssCorrections | None = None,
    options: EpochSolverOptions | None = None,
    initial_position: Vec | None = None,
    drift_prior: DriftPrior | None = None,
    doppler_noise: DopplerNoise | None = None,
    models: SatModels | None = None,
) -> EpochResult:
    """SPP (differential when `corrections` is given) and, if it has a fix, Doppler velocity.

    `drift_prior` is the receiver's drift memory (`next_drift_prior`) and `doppler_noise` its
    learned Doppler noise, for the Doppler solve's few-satellite mode
    (`DopplerOptions.few_satellites`).
    """
    opt = options or EpochSolverOptions()
    prepared = prepare_epoch(epoch, nav, opt.systems)
    spp = solve_spp(
        prepared,
        nav,
        opt.spp,
        corrections_m=corrections.corrections_m if corrections is not None else None,
        initial_position=initial_position,
        models=models,
    )
    # Doppler needs the position only for the line-of-sight vectors: 100 m of error changes them
    # by 5e-6 rad, about 0.02 m/s of velocity. So when SPP fails (RAIM in a canyon, where several
    # NLOS pseudoranges are present but their Doppler is often clean or excludable) the velocity
    # is still solved at the receiver's previous fix instead of being dropped with the position.
    # (at the fix, the point where SPP evaluated the satellites, a decimetre at most from it)
    at = spp.model_position if spp.ok else initial_position
    vel = (
        solve_doppler_velocity(prepared, at, opt.doppler, drift_prior, doppler_noise)
        if at is not None and np.all(np.isfinite(at))
        else None
    )
    return EpochResult(prepared, spp, vel, corrections)


@dataclass
class ReceiverMemory:
    """What one receiver's front end carries from epoch to epoch: its last fix, where the next
    SPP starts, its clock-drift memory (`next_drift_prior`) and its learned Doppler noise."""

    fix: Vec | None = None
    models: SatModels | None = None  # the last fix's satellite models, where the next SPP starts
    drift: DriftPrior | None = None
    doppler_noise: DopplerNoise = field(default_factory=DopplerNoise)

    def update(self, res: EpochResult, options: DopplerOptions | None = None) -> None:
        """Take epoch `res` in: a new fix when SPP solved, the drift memory, and a full-sky
        Doppler solve's residuals into the noise (a few-satellite one leans on its pseudo-rows)."""
        self.drift = next_drift_prior(self.drift, res)
        v = res.velocity
        if v is not None and v.ok and not v.few_satellites:
            opt = (options or DopplerOptions()).standstill
            self.doppler_noise = self.doppler_noise.add(v.chi2, v.dof, opt)
        if res.spp.ok:
            self.fix = res.spp.position
            self.models = res.spp.models.merged(self.models) if res.spp.models is not None else None


def solve_next(
    epoch: ObsEpoch,
    nav: NavData,
    memory: ReceiverMemory,
    corrections: DgnssCorrections | None = None,
    options: EpochSolverOptions | None = None,
) -> EpochResult:
    """`solve_epoch` for a receiver's next epoch: it starts from and updates `memory`."""
    opt = options or EpochSolverOptions()
    res = solve_epoch(
        epoch, nav, corrections, opt, memory.fix, memory.drift, memory.doppler_noise, memory.models
    )
    memory.update(res, opt.doppler)
    return res


def next_drift_prior(prev: DriftPrior | None, res: EpochResult) -> DriftPrior | None:
    """A receiver's drift memory after epoch `res`: a drift solved with a full sky replaces it.

    A few-satellite drift leans on the memory itself, so it must not renew it (its age, and so
    its sigma, would stop growing).
    """
    v = res.velocity
    if v is not None and v.ok and not v.few_satellites:
        return DriftPrior(v.drift_mps, v.time)
    return prev


def first_fix(epochs: Iterable[ObsEpoch], nav: NavData, tries: int = 30) -> Vec | None:
    """A receiver's position from the first of its epochs that SPP fixes (at most `tries`), None
    if none does: where a receiver is, to metres, e.g. for its distance to a base station."""
    for epoch in itertools.islice(epochs, tries):
        res = solve_epoch(epoch, nav)
        if res.spp.ok:
            return np.asarray(res.spp.position, dtype=float)
    return None
