"""The estimator contract: one epoch of the fleet in (`EpochInput`), the fleet's estimates out.

These are plain frozen dataclasses (no GTSAM types), built by the per-vehicle step from its node
message, so the estimator can be fed from the bus, from `coplane eval` or from a unit test alike.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

from coplane.gtime import GpsTime
from coplane.plane.fit import constraint_error
from coplane.typing import Mat, Vec


@dataclass(frozen=True)
class PseudorangeObs:
    """A corrected pseudorange ready for GTSAM's PseudorangeFactor.

    Model: rho_m = |p - sat_pos_m| + c * (clock_s[system] - sat_clock_s) + noise(sigma_m), where
    sat_pos_m is already rotated into the ECEF frame at reception (Sagnac) and rho_m has TGD,
    ionosphere and troposphere (standalone) or the DGNSS correction removed.
    """

    sat: str
    rho_m: float
    sat_pos_m: Vec
    sat_clock_s: float
    sigma_m: float
    elevation_rad: float = float("nan")
    cn0_dbhz: float = float("nan")
    # 1-sigma of the part of the error that stays the same over the window (the broadcast
    # atmosphere's residual standalone, the base station's own errors with DGNSS:
    # `gnss.weighting.common_error_sigma_m`); NaN: unknown. Only the reported covariance uses it.
    common_sigma_m: float = float("nan")

    @property
    def system(self) -> str:
        return self.sat[0]


@dataclass(frozen=True)
class PseudorangeColumns:
    """A vehicle epoch's pseudoranges as columns, one row per satellite (`PseudorangeObs`'s model).

    The form the fusion server builds from a node message: a few numpy arrays made in one pass
    over the message, where an object per satellite cost more than the validation that turns them
    into arrays anyway (`validate._valid_pseudoranges`; docs/performance-scale.md, "Server
    overhead"). Untrusted like every input: the validation checks shapes and values.
    """

    sats: tuple[str, ...]
    sat_pos_m: Mat  # (n, 3), ECEF at reception
    rho_m: Vec
    sat_clock_s: Vec
    sigma_m: Vec
    elevation_rad: Vec  # NaN where not reported
    cn0_dbhz: Vec  # NaN where not reported
    common_sigma_m: Vec | None = None  # PseudorangeObs.common_sigma_m; None: unknown for every row

    def __len__(self) -> int:
        return len(self.sats)


@dataclass(frozen=True)
class PlaneObs:
    """Antenna-height plane (paper eq. 12): unit upward normal n, offset d with n.p + d = 0."""

    normal: Vec
    d_m: float
    sigma_m: float
    status: str = "available"  # "available" | "available-after-fe"

    def error(self, p: Vec) -> float:
        """Paper eq. 24 (signed metres, positive above the plane): the one definition in plane.fit."""
        return constraint_error(self.normal, self.d_m, p)


@dataclass(frozen=True)
class VelocityObs:
    """Doppler least-squares velocity (paper eq. 34) in ECEF, with its 1-sigma per axis."""

    velocity_mps: Vec
    sigma_mps: float
    standstill: bool = False  # zero from the front end's standstill test (coplane.gnss.standstill)


@dataclass(frozen=True)
class VehicleEpochInput:
    vehicle_id: str
    time: GpsTime  # nominal epoch time
    pseudoranges: tuple[PseudorangeObs, ...] | PseudorangeColumns = ()
    velocity: VelocityObs | None = None
    plane: PlaneObs | None = None
    spp_position: Vec | None = None  # initial guess; None when SPP had no fix
    clock_drift_mps: float | None = None  # Doppler clock drift, for the clock between factor
    antenna_height_m: float | None = None  # above the road: the height links (FgoConfig) need it
    # whether the receiver reported any Doppler this epoch: False for one that gives none (an RTCM
    # MSM4 stream, a pseudorange-only log), None when it tracked no satellite (nothing to tell)
    doppler_observed: bool | None = True


@dataclass(frozen=True)
class RangeObs:
    """Round-trip inter-vehicle range (clock-free, symmetric), paper eq. 25."""

    a: str
    b: str
    range_m: float
    sigma_m: float


@dataclass(frozen=True)
class EpochInput:
    time: GpsTime
    vehicles: dict[str, VehicleEpochInput]
    ranges: tuple[RangeObs, ...] = ()


@dataclass(frozen=True)
class VehicleEstimate:
    vehicle_id: str
    time: GpsTime
    position_m: Vec
    covariance_m2: Vec  # 3x3 ECEF marginal (NaN when not computed)
    clocks_s: dict[str, float] = field(default_factory=dict)
    n_pseudoranges: int = 0
    n_ranges: int = 0
    plane_used: bool = False
    has_gnss_fix: bool = True  # False: carried by velocity/plane/ranging only
    # the node's well-formed pseudoranges the estimator left out of this epoch (its FDE or
    # innovation gate, the cooperative check, a dead-reckoned epoch), sorted: `left_out`
    excluded_satellites: tuple[str, ...] = ()


def left_out(given: Sequence[str], kept: Sequence[str]) -> tuple[str, ...]:
    """The satellites of `given` not in `kept`, sorted: what `VehicleEstimate.excluded_satellites`
    reports, so that a user sees which satellites an epoch's estimate did without."""
    return tuple(sorted(set(given) - set(kept)))


@dataclass(frozen=True)
class FleetSolution:
    time: GpsTime
    estimates: dict[str, VehicleEstimate]
    solve_time_s: float
    factor_counts: dict[str, int]
    iterations: int = 0
    # the graph's error before and after the solve, summed over the clusters; NaN where the
    # solver does not evaluate it (the iSAM2 smoother, the baselines)
    error_before: float = float("nan")
    error_after: float = float("nan")
    # vehicles present in the EpochInput without an estimate, with the reason (e.g. too few
    # measurements for a first position, solver failure)
    skipped: dict[str, str] = field(default_factory=dict)
    # invalid measurements dropped by the estimator, by kind ("pseudorange", "range", ...)
    rejected: dict[str, int] = field(default_factory=dict)
    n_clusters: int = 0  # clusters solved this epoch


class Estimator(Protocol):
    """What the fusion step drives: one fleet epoch in, the fleet's estimates out.

    The factor graph (`coplane.fgo.FusionEstimator`) and the baselines (`coplane.baselines`)
    implement it; each starts from `coplane.estimation.validate_epoch`, so every method sees the
    same validated measurements and runs through the same steps, evaluator and services.
    """

    def step(self, epoch: EpochInput) -> FleetSolution: ...


@dataclass(frozen=True)
class VehicleSeed:
    """A vehicle's last solved state from before a restart (the fusion server's solution log).

    An estimator that can resume takes it as the prior of the vehicle's next state, predicted to
    that epoch and with its covariance grown by the elapsed time; a seed older than the estimator
    cares about is ignored.
    """

    vehicle_id: str
    time: GpsTime
    position_m: Vec
    covariance_m2: Vec | None = None  # 3x3 ECEF, None when it was not computed
    clocks_s: dict[str, float] = field(default_factory=dict)


@runtime_checkable
class SeedableEstimator(Estimator, Protocol):
    """An estimator that can resume vehicles from `VehicleSeed`s (optional part of the contract)."""

    def seed(self, seed: VehicleSeed) -> None: ...


def seed_estimator(estimator: Estimator, seeds: Iterable[VehicleSeed]) -> int:
    """Hand `seeds` to `estimator` if it can take them; returns how many it was given (0: it
    cannot, and starts every vehicle afresh as before, which is correct, only less informed)."""
    if not isinstance(estimator, SeedableEstimator):
        return 0
    n = 0
    for s in seeds:
        estimator.seed(s)
        n += 1
    return n
