"""VehicleStep's plane sigma: "covariance" propagates the fit to the vehicle, "offset" does not.

A synthetic fleet history (no GNSS: the vehicle's centre is its last fused position) on a level
road 10 m wide; the vehicle asks for its plane at growing distances from the points' centroid.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from coplane.estimation.limits import MAX_PLANE_SIGMA_M
from coplane.geo import enu_to_ecef, geodetic_to_ecef
from coplane.gtime import GpsTime
from coplane.messages import PlaneReport, SolutionMessage, VehicleState
from coplane.methods import get_method
from coplane.plane.config import PlaneConfig, SigmaModel
from coplane.plane.detect import construct_plane
from coplane.recording.model import NavData
from coplane.steps import VehicleStep, VehicleStepConfig, epoch_time, plane_report

REF = geodetic_to_ecef(math.radians(39.98), math.radians(116.31), 50.0)
T0 = GpsTime(2300, 100_000.0)
H = 1.6
SIGMA_UP = 0.5
OTHERS = ("u2", "u3", "u4", "u5")


def _state(vid: str, enu: np.ndarray) -> VehicleState:
    p = enu_to_ecef(enu + np.array([0.0, 0.0, H]), REF)
    cov = np.diag([1.0, 1.0, 1.0]) * SIGMA_UP**2  # isotropic: the same sigma along any up
    return VehicleState(
        vehicle_id=vid,
        position_ecef_m=(float(p[0]), float(p[1]), float(p[2])),
        covariance_m2=[float(x) for x in cov.reshape(9)],
        antenna_height_m=H,
        n_pseudoranges=8,
        n_ranges=0,
        plane_used=False,
        has_gnss_fix=True,
    )


def _solution(k: int, states: list[VehicleState]) -> SolutionMessage:
    return SolutionMessage(
        fleet="f", method="pc", seq=k, epoch=epoch_time(T0 + float(k)), vehicles=states, solve_time_s=0.0
    )


def plane_at(north_m: float, model: SigmaModel) -> PlaneReport:
    """u1's plane when it is `north_m` ahead of the others' points (16 points, 4 lanes, 4 epochs)."""
    step = VehicleStep(
        "f", "u1", H, NavData(), get_method("pc"), VehicleStepConfig(plane=PlaneConfig(sigma_model=model))
    )
    step.process(T0, None)  # joins the cooperation at T0
    g = np.random.default_rng(0)
    for k in range(4):
        states = [
            _state(v, np.array([-4.5 + 3.0 * i, -6.0 + 4.0 * k, g.normal(0.0, 0.05)]))
            for i, v in enumerate(OTHERS)
        ]
        if k == 3:
            states.append(_state("u1", np.array([0.0, north_m, 0.0])))
        step.ingest(_solution(k, states))
    msg = step.process(T0 + 4.0, None)
    assert msg.plane is not None and msg.plane.status == "available", msg.plane
    return msg.plane


def test_plane_sigma_grows_with_distance_from_the_centroid() -> None:
    near, mid, far = (plane_at(d, "covariance") for d in (0.0, 15.0, 30.0))
    assert near.sigma_m is not None and mid.sigma_m is not None and far.sigma_m is not None
    assert near.sigma_m < mid.sigma_m < far.sigma_m
    assert far.sigma_m > 1.3 * near.sigma_m
    assert near.tilt_sigma_rad is not None and near.tilt_sigma_rad > 0.0
    # at the centroid: about the offset sigma, one vehicle error over the 4 (5) vehicles
    assert near.offset_sigma_m == pytest.approx(SIGMA_UP / 2, rel=0.25)
    # the old model is the same wherever the vehicle is, and has no tilt
    old = [plane_at(d, "offset") for d in (0.0, 30.0)]
    assert old[0].tilt_sigma_rad is None
    assert old[0].sigma_m == pytest.approx(old[1].sigma_m, rel=0.1)
    assert far.sigma_m > 1.3 * (old[1].sigma_m or 0.0)


def test_plane_report_takes_the_propagated_sigma_and_caps_it() -> None:
    """With `sigma_m` given, the report carries it (and the tilt); beyond the wire bound it is capped."""
    g = np.random.default_rng(1)
    enu = np.column_stack([g.uniform(-20, 20, 20), g.uniform(-20, 20, 20), g.normal(0.0, 0.02, 20)])
    p = construct_plane(enu_to_ecef(enu, REF), H, PlaneConfig(), np.random.default_rng(0))
    r = plane_report(p, 0.3, 2.5, 0.02)
    assert (r.sigma_m, r.offset_sigma_m, r.tilt_sigma_rad) == (2.5, 0.3, 0.02)
    PlaneReport.model_validate_json(r.model_dump_json())
    big = plane_report(p, 500.0, 1e4, 9.0)
    assert (big.sigma_m, big.offset_sigma_m, big.tilt_sigma_rad) == (MAX_PLANE_SIGMA_M, 100.0, math.pi)
    assert plane_report(p).tilt_sigma_rad is None
