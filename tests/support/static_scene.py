"""Small static scenes for the baseline tests: receivers at known offsets, exact measurement models.

`scene` builds EpochInputs for static receivers: satellites from `fgo_synthetic`, pseudoranges
rho = |p - s| + b_sys - c dt_s (+ optional per-satellite common-mode error shared by all receivers,
+ white noise), a Doppler velocity and clock drift with known noise.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace

import numpy as np

from coplane.baselines.measurements import VehicleMeasurements, vehicle_measurements
from coplane.estimation.contract import EpochInput, PseudorangeObs, VehicleEpochInput, VelocityObs
from coplane.estimation.validate import validate_vehicle as _validate_vehicle
from coplane.geo import enu_rotation, geodetic_to_ecef
from coplane.gnss.constants import C
from coplane.gtime import GpsTime
from support.fgo_synthetic import REF_H, REF_LAT, REF_LON, _satellites

Vec = np.ndarray


def validate_vehicle(vid: str, vin: object, t: object, rejected: object) -> VehicleMeasurements | str:
    """The baselines' measurements of one validated vehicle epoch (or why it was skipped)."""
    v = _validate_vehicle(vid, vin, t, rejected)  # type: ignore[arg-type]
    return v if isinstance(v, str) else vehicle_measurements(v)


@dataclass
class Scene:
    epochs: list[EpochInput]
    truth: dict[str, Vec]  # static antenna positions
    clocks: dict[str, dict[str, float]]  # receiver clocks at epoch 0 (m) per system
    rot: np.ndarray  # ENU rows at the reference point

    def enu_error(self, vid: str, p: Vec) -> Vec:
        return self.rot @ (np.asarray(p) - self.truth[vid])


def scene(
    offsets_enu: Mapping[str, tuple[float, float, float]],
    n_epochs: int,
    *,
    seed: int = 0,
    sigma: float = 1.0,
    n_gps: int = 8,
    n_bds: int = 6,
    velocity_sigma: float = 0.1,
    common_sigma: float = 0.0,
    noise: bool = True,
    drift_mps: float = 30.0,
    elevations: bool = True,
) -> Scene:
    """Static receivers at ENU offsets from the reference point, 1 s epochs."""
    rng = np.random.default_rng(seed)
    ref = geodetic_to_ecef(REF_LAT, REF_LON, REF_H)
    rot = enu_rotation(REF_LAT, REF_LON)
    sats = _satellites(rng, ref, rot, n_gps, n_bds)
    truth = {v: ref + rot.T @ np.asarray(o, dtype=float) for v, o in offsets_enu.items()}
    clocks = {v: {"G": float(rng.uniform(-3e4, 3e4))} for v in truth}
    for v in truth:
        clocks[v]["C"] = clocks[v]["G"] + float(rng.uniform(-50, 50))
    common = {s.sat: rng.normal(0.0, common_sigma) if common_sigma > 0 else 0.0 for s in sats}
    epochs = []
    for k in range(n_epochs):
        t = GpsTime(2300, 345_600.0 + k)
        vehicles = {}
        for v, p in truth.items():
            prs = []
            for s in sats:
                sp = s.pos0 + s.vel * k
                u = (sp - p) / np.linalg.norm(sp - p)
                el = math.asin(float(rot[2] @ u))
                rho = float(np.linalg.norm(p - sp)) + clocks[v][s.sat[0]] + drift_mps * k - C * s.clock_s
                rho += common[s.sat] + (rng.normal(0.0, sigma) if noise else 0.0)
                prs.append(PseudorangeObs(s.sat, rho, sp, s.clock_s, sigma, el if elevations else math.nan))
            vel = VelocityObs(rng.normal(0.0, velocity_sigma, 3) if noise else np.zeros(3), velocity_sigma)
            drift = drift_mps + (rng.normal(0.0, velocity_sigma) if noise else 0.0)
            spp = p + (rng.normal(0.0, 3.0, 3) if noise else np.zeros(3))
            vehicles[v] = VehicleEpochInput(v, t, tuple(prs), vel, None, spp, drift)
        epochs.append(EpochInput(t, vehicles))
    return Scene(epochs, truth, clocks, rot)


def with_vehicle(ep: EpochInput, vid: str, **changes: object) -> EpochInput:
    """The epoch with one vehicle's input changed (dataclasses.replace on it)."""
    vehicles = dict(ep.vehicles)
    vehicles[vid] = replace(vehicles[vid], **changes)  # type: ignore[arg-type]
    return replace(ep, vehicles=vehicles)
