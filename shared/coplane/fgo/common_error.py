"""The covariance of the errors the window cannot average, added to what the estimator reports.

The factor graph models every pseudorange error as white: independent from epoch to epoch. Without
a base station part of it is not: the broadcast ionosphere's and troposphere's residuals drift
over tens of minutes, so over a window of seconds they are a constant, which the graph's marginal
averages down with the epochs. A single scale on the marginal (`FgoConfig.covariance_scale`, chosen
with DGNSS) then left the height over-confident: on the simulated standalone drives 0.73-0.84 of
the vertical errors fell inside the 95 % interval (docs/fgo.md, "An honest covariance").

What such errors do to one epoch's position is what a snapshot least-squares fit does with them:
for the kept pseudoranges with common sigmas s_i (`PseudorangeObs.common_sigma_m`), unit vectors
u_i and a clock per system, the position block of (H^T S^-1 H)^-1 with H = [-u_i, e_system(i)].
Its shape is the geometry's: an error that grows at low elevation goes mostly into the height.
Written with numpy: a 3x3 block of a small inverse, which no GTSAM factor computes.
"""

from __future__ import annotations

import numpy as np

from coplane.estimation.validate import ValidPseudoranges
from coplane.fgo.screen import design_matrix
from coplane.gnss.weighting import RTKLIB_MIN_EL_RAD
from coplane.typing import Mat, Vec


def common_error_covariance(prs: ValidPseudoranges, position: Vec, dgnss_zenith_m: float = 0.0) -> Mat | None:
    """ECEF 3x3 covariance of the position error the rows' common errors make at `position`, or
    None when there is none to add or the rows do not determine it: a common sigma unknown (NaN)
    or 0 (DGNSS: no claim about the epoch), fewer rows than unknowns plus one, a singular
    geometry. `dgnss_zenith_m` > 0: the DGNSS rows (common sigma 0) get that / sin(elevation)
    instead, a model of what the base station leaves (`FgoConfig.covariance_common_dgnss_m`)."""
    sig = prs.common_sigma
    if sig is None or len(prs) == 0:
        return None
    if dgnss_zenith_m > 0.0:
        with np.errstate(invalid="ignore"):
            base = dgnss_zenith_m / np.sin(np.maximum(prs.elevation, RTKLIB_MIN_EL_RAD))
        sig = np.where(sig == 0.0, base, sig)
    if not bool(np.all(np.isfinite(sig) & (sig > 0.0))):
        return None
    if len(prs) < 3 + len(set(prs.systems)) + 1:
        return None
    h = design_matrix(prs, position)[0]
    info = (h.T / (sig * sig)) @ h
    try:
        cov = np.linalg.inv(info)[:3, :3]
    except np.linalg.LinAlgError:
        return None
    if not np.all(np.isfinite(cov)):
        return None
    return 0.5 * (cov + cov.T)
