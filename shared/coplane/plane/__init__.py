"""Road-plane construction (paper Sec. III): SVD fit, availability detection, RANSAC FE, history.

- `history.PositionHistory`: the fleet's solved positions projected to the road (eqs. 1-2) and the
  fitting-point query around a vehicle's SPP fix (eq. 3);
- `fit.fit_plane`: total-least-squares plane by SVD (eqs. 6-11), normal oriented upward;
- `detect.construct_plane`: availability detection (eqs. 14-16) and RANSAC fault exclusion
  (Algorithm 1), translated to antenna height (eqs. 12-13) -> `RoadPlane`;
- `uncertainty.plane_uncertainty`: the fitted plane's first-order covariance (offset and tilt) and
  the factor sigma it implies at the vehicle's position;
- the per-vehicle step (history query + construction) is `coplane.steps.VehicleStep`.

Plane convention: ``n . p + d = 0``, ``n`` unit and upward; the antenna plane is
``d_antenna = d_road - h``; the factor error (eq. 24) is ``n . p + d_antenna``. See docs/planes.md.
"""

from coplane.plane.config import PlaneConfig
from coplane.plane.detect import (
    PlaneStatus,
    RoadPlane,
    construct_plane,
    detection_failures,
    ransac_inliers,
)
from coplane.plane.fit import Degenerate, PlaneFit, antenna_offset, constraint_error, fit_plane
from coplane.plane.history import HistorySample, PositionHistory, cell_key, project_to_road
from coplane.plane.uncertainty import PlaneUncertainty, plane_uncertainty

__all__ = [
    "Degenerate",
    "HistorySample",
    "PlaneConfig",
    "PlaneFit",
    "PlaneStatus",
    "PlaneUncertainty",
    "PositionHistory",
    "RoadPlane",
    "antenna_offset",
    "cell_key",
    "constraint_error",
    "construct_plane",
    "detection_failures",
    "fit_plane",
    "plane_uncertainty",
    "project_to_road",
    "ransac_inliers",
]
