"""Conversions between the library's values and the wire models the steps exchange.

The steps speak `coplane.messages` at their edges; these helpers keep every conversion (times,
vectors, covariances, planes) in one place so both steps and the evaluator convert alike.
"""

from __future__ import annotations

import itertools
import math
import zlib
from typing import TYPE_CHECKING

import numpy as np

from coplane.estimation.contract import PseudorangeColumns
from coplane.estimation.limits import MAX_PLANE_SIGMA_M
from coplane.gnss.weighting import common_error_sigma_m
from coplane.gtime import GpsTime
from coplane.messages import EpochTime, NodeMessage, PlaneReport, PlaneSourceName, PlaneSummary
from coplane.plane.detect import PlaneStatus, RoadPlane
from coplane.typing import AnyArray

MAX_OFFSET_SIGMA_M = 100.0  # PlaneReport.offset_sigma_m's bound

STATUS_NAME = {
    PlaneStatus.AVAILABLE: "available",
    PlaneStatus.AVAILABLE_AFTER_FE: "available-after-fe",
    PlaneStatus.UNAVAILABLE: "unavailable",
}

if TYPE_CHECKING:
    from coplane.roadmap import MapPlane


def epoch_time(t: GpsTime) -> EpochTime:
    return EpochTime(week=t.week, tow=t.tow)


def gps_time(e: EpochTime) -> GpsTime:
    return GpsTime(e.week, e.tow)


def tuple3(v: AnyArray) -> tuple[float, float, float]:
    return (float(v[0]), float(v[1]), float(v[2]))


def cov9(c: AnyArray) -> list[float] | None:
    c = np.asarray(c, dtype=float)
    return [float(x) for x in c.reshape(9)] if np.all(np.isfinite(c)) else None


def stable_seed(*parts: int | str) -> list[int]:
    """A seed sequence that does not depend on Python's per-process hash randomisation."""
    return [zlib.crc32(p.encode()) if isinstance(p, str) else int(p) & 0xFFFFFFFF for p in parts]


def plane_report(
    p: RoadPlane,
    offset_sigma: float = 0.0,
    sigma_m: float | None = None,
    tilt_sigma_rad: float | None = None,
    source: PlaneSourceName | None = None,
) -> PlaneReport:
    """The wire form of a plane.

    The factor's sigma is `sigma_m` when given (the propagated covariance at the vehicle,
    `plane.uncertainty`), else the fit residual and `offset_sigma` in quadrature. Sigmas are
    capped at the wire's bound: a plane that uncertain constrains nothing anyway.
    """
    if p.status == PlaneStatus.UNAVAILABLE:
        return PlaneReport(
            status="unavailable",
            reason=p.reason,
            n_points_initial=p.n_points_initial,
            n_points_used=p.n_points_used,
            residual_max_m=p.residual_max_m if math.isfinite(p.residual_max_m) else None,
            source=source,
        )
    return PlaneReport(
        status=STATUS_NAME[p.status],  # type: ignore[arg-type]
        reason=p.reason,
        normal=tuple3(p.normal),
        d_antenna_m=float(p.d_antenna),
        d_road_m=float(p.d_road),
        sigma_m=min(
            float(math.hypot(p.sigma_m, offset_sigma) if sigma_m is None else sigma_m), MAX_PLANE_SIGMA_M
        ),
        offset_sigma_m=min(float(offset_sigma), MAX_OFFSET_SIGMA_M),
        tilt_sigma_rad=None if tilt_sigma_rad is None else min(float(tilt_sigma_rad), math.pi),
        residual_max_m=float(p.residual_max_m),
        residual_rms_m=float(p.residual_rms_m),
        n_points_initial=p.n_points_initial,
        n_points_used=p.n_points_used,
        centroid_ecef_m=tuple3(p.centroid),
        source=source,
    )


def map_plane_report(p: MapPlane) -> PlaneReport:
    """The wire form of a road-surface map's plane at the vehicle (docs/roadmap.md).

    It is a plane like a fitted one (normal, offsets, the factor's sigma at the vehicle), so the
    fusion step and every estimator use it unchanged; `source` and the tile say where it came from.
    """
    return PlaneReport(
        status="available",
        normal=tuple3(p.normal),
        d_antenna_m=float(p.d_antenna),
        d_road_m=float(p.d_road),
        sigma_m=min(float(p.sigma_m), MAX_PLANE_SIGMA_M),
        offset_sigma_m=min(float(p.offset_sigma_m), MAX_OFFSET_SIGMA_M),
        tilt_sigma_rad=min(float(p.tilt_sigma_rad), math.pi),
        centroid_ecef_m=tuple3(p.centroid),
        source="map",
        map_tile=str(p.key),
        map_passes=int(p.n_passes),
    )


def plane_summary(p: PlaneReport | None) -> PlaneSummary | None:
    if p is None:
        return None
    return PlaneSummary(
        status=p.status,
        reason=p.reason,
        residual_max_m=p.residual_max_m,
        residual_rms_m=p.residual_rms_m,
        sigma_m=p.sigma_m,
        offset_sigma_m=p.offset_sigma_m,
        n_points_initial=p.n_points_initial,
        n_points_used=p.n_points_used,
        source=p.source,
        map_tile=p.map_tile,
    )


def doppler_observed(m: NodeMessage) -> bool | None:
    """Whether the node's receiver reported any Doppler this epoch (its velocity, or a Doppler
    on any tracked satellite); None when it tracked none. A receiver without Doppler (an RTCM MSM4
    stream, a pseudorange-only log) gets the estimator's motion model for that case
    (`FgoConfig.no_doppler_velocity`)."""
    if m.velocity is not None:
        return True
    if not m.satellites:
        return None
    return any(d is not None for d in m.satellites.doppler_hz)


def pseudorange_columns(m: NodeMessage) -> PseudorangeColumns:
    """The pseudoranges a node message marks used, as the estimator's columns: arrays straight
    from the message's own columns (the fusion server does this for every vehicle of every epoch).
    The numbers go through one (n, 7) array, the layout the estimator has always been given."""
    s = m.satellites
    used = np.array(s.used, dtype=bool)
    cn0 = [math.nan if c is None else c for c in s.cn0_dbhz]
    dgnss = [d is not None for d in s.dgnss_m]
    rows = np.array([s.rho_m, s.sat_clock_s, s.sigma_m, s.elevation_deg, cn0, s.iono_m, dgnss], dtype=float)
    num = np.ascontiguousarray(rows[:, used].T)
    elevation = np.radians(num[:, 3])
    return PseudorangeColumns(
        sats=tuple(itertools.compress(s.sat, s.used)),
        sat_pos_m=np.array(s.sat_pos_ecef_m, dtype=float).reshape(-1, 3)[used],  # (0, 3) when none
        rho_m=num[:, 0],
        sat_clock_s=num[:, 1],
        sigma_m=num[:, 2],
        elevation_rad=elevation,
        cn0_dbhz=num[:, 4],
        common_sigma_m=common_error_sigma_m(elevation, num[:, 5], num[:, 6] != 0.0),
    )
