"""Fused solutions as evidence for the road-surface map: one MapSample per solved vehicle-epoch.

Both learners use it: `coplane map build` (evaluate/map_build.py, from an in-process run) and the
fusion server (services/fusion_server/road_map.py, from each solution as it is made). A solution
that leaned on the map's own plane carries that plane's height and sigma, so the builder can take
the map's information back out: a map must not learn from itself.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from coplane.geo import ecef_to_geodetic, up_vector
from coplane.messages import NodeMessage, PlaneReport, SolutionMessage
from coplane.roadmap import MapSample
from coplane.steps.wire import gps_time
from coplane.typing import AnyArray as Vec


def map_plane_height(report: PlaneReport | None, used: bool, position: Vec) -> tuple[float, float] | None:
    """(antenna ellipsoidal height the map's plane implies at `position`, its sigma), or None.

    Only for an epoch whose solution used a plane from the map: its height then leans on the map.
    The plane's signed distance n.p + d_antenna is along its normal; divided by n.up it is the
    vertical offset of the antenna from where the plane puts it.
    """
    if not used or report is None or report.source != "map":
        return None
    if report.normal is None or report.d_antenna_m is None or report.sigma_m is None:
        return None
    n = np.asarray(report.normal, dtype=float)
    cos_tilt = float(n @ up_vector(position))
    if cos_tilt <= 0.5:  # not a road plane; the fusion server's admission rejects these anyway
        return None
    h_fused = float(ecef_to_geodetic(position)[2])
    dist = float(n @ position + report.d_antenna_m)
    return h_fused - dist / cos_tilt, float(report.sigma_m) / cos_tilt


def solution_samples(
    sol: SolutionMessage, msgs: Mapping[str, NodeMessage], antenna_heights: Mapping[str, float]
) -> list[MapSample]:
    """The map samples of one fleet solution (`msgs`: the node messages it was solved from; their
    plane reports say whether a vehicle's plane came from the map). Vehicles without a known
    antenna height are left out: the road point would be wrong by it."""
    t = gps_time(sol.epoch).seconds
    out = []
    for v in sol.vehicles:
        h = antenna_heights.get(v.vehicle_id)
        if h is None:
            continue
        p = np.array(v.position_ecef_m, dtype=float)
        msg = msgs.get(v.vehicle_id)
        mapped = map_plane_height(msg.plane if msg is not None else None, v.plane_used, p)
        out.append(
            MapSample(
                vehicle_id=v.vehicle_id,
                time_s=t,
                position_ecef_m=p,
                covariance_m2=None if v.covariance_m2 is None else np.array(v.covariance_m2).reshape(3, 3),
                antenna_height_m=h,
                has_gnss_fix=v.has_gnss_fix,
                flagged=False,
                map_plane_height_m=None if mapped is None else mapped[0],
                map_plane_sigma_m=None if mapped is None else mapped[1],
            )
        )
    return sorted(out, key=lambda s: s.vehicle_id)
