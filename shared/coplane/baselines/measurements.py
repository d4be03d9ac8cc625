"""The EKF-family baselines' view of one vehicle epoch: validated arrays plus what filters need.

Built from `coplane.estimation.ValidVehicle` (the one validated container every estimator
consumes), adding the two quantities these filters use: rho_c = rho + c dt_s (so the model is
|p - s| + b) and sigma_rx, the receiver-specific part of the pseudorange sigma (the elevation /
C/N0 model without the broadcast-ionosphere residual, which nearby receivers share) used for
differences between receivers.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from coplane.estimation.validate import ValidVehicle
from coplane.gnss.constants import C
from coplane.gnss.weighting import pseudorange_sigma_m
from coplane.typing import Mat, Vec

# the Doppler drift row uses the velocity sigma too: without a velocity this is its sigma
DEFAULT_VELOCITY_SIGMA_MPS = 0.6


@dataclass
class VehicleMeasurements:
    """One vehicle's epoch after validation, as arrays (rho_c = rho + c dt_s: model |p - s| + b)."""

    vehicle_id: str
    sats: list[str]
    systems: list[str]
    sat_pos: Mat  # (n, 3) ECEF at reception
    rho_c: Vec  # (n,)
    sigma: Vec  # (n,) node sigma
    sigma_rx: Vec  # (n,) receiver-specific part (no common-mode iono residual): for differences
    elevation: Vec  # (n,) rad, NaN when unknown
    velocity: Vec | None = None
    velocity_sigma: float = 0.6
    drift: float | None = None
    spp: Vec | None = None

    def __len__(self) -> int:
        return len(self.sats)

    def subset(self, keep: Sequence[int]) -> VehicleMeasurements:
        k = list(keep)
        return VehicleMeasurements(
            self.vehicle_id,
            [self.sats[i] for i in k],
            [self.systems[i] for i in k],
            self.sat_pos[k],
            self.rho_c[k],
            self.sigma[k],
            self.sigma_rx[k],
            self.elevation[k],
            self.velocity,
            self.velocity_sigma,
            self.drift,
            self.spp,
        )


def vehicle_measurements(v: ValidVehicle) -> VehicleMeasurements:
    """The filters' view of a validated vehicle epoch."""
    p = v.pseudoranges
    sigma_rx = p.sigma.copy()
    for k in range(len(p)):
        el = float(p.elevation[k])
        if math.isfinite(el):
            sigma_rx[k] = min(float(p.sigma[k]), pseudorange_sigma_m(el, float(p.cn0[k]), p.systems[k]))
    return VehicleMeasurements(
        v.vehicle_id,
        list(p.sats),
        list(p.systems),
        p.sat_pos,
        p.rho + C * p.sat_clock,
        p.sigma,
        sigma_rx,
        p.elevation,
        v.velocity,
        v.velocity_sigma if v.velocity is not None else DEFAULT_VELOCITY_SIGMA_MPS,
        v.drift,
        v.spp,
    )


def clock_residuals(m: VehicleMeasurements, p: Vec) -> dict[str, float]:
    """Median over each system of rho_c - |p - s|: that system's clock seen from position p."""
    if not len(m):
        return {}
    r = m.rho_c - np.linalg.norm(m.sat_pos - p, axis=1)
    sys = np.array(m.systems)
    return {s: float(np.median(r[sys == s])) for s in sorted(set(m.systems))}
