"""Parameters of road-plane construction (paper Sec. III), with the paper's values as defaults.

A frozen dataclass (not a pydantic model) so callers can derive variants with
`dataclasses.replace(cfg, fault_exclusion=False)`; it is validated on construction because it may
come from a TOML file or a command line.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

from coplane.errors import require_finite_positive

SigmaModel = Literal["offset", "covariance"]
SIGMA_MODELS: tuple[SigmaModel, ...] = ("offset", "covariance")


@dataclass(frozen=True)
class PlaneConfig:
    """How a vehicle fits, checks and repairs its road plane; see docs/planes.md."""

    range_fitting_m: float = 50.0
    """Eq. (3): history points closer than this (3-D, to the vehicle's SPP fix) are fitting points."""

    n_max: int = 20
    """N_f,max (Sec. 3.1): more candidates than this are randomly down-selected (bounds the cost)."""

    n_min: int = 15
    """N_f,min (eq. 16): a plane needs at least this many (inlier) points. With n_max = 20 it lets
    fault exclusion drop at most 5 points."""

    t_f_m: float = 5.0
    """T_f (eq. 16, Algorithm 1): maximum fitting residual and RANSAC inlier distance. The paper's
    5 m is large for a road (a crest is only rejected when its radius is below ~170 m over a 100 m
    span); it suits metre-level urban GNSS positions. Smaller values reject curvature sooner."""

    ransac_iterations: int = 7
    """I_max (Algorithm 1), 'set to 7 by experience' in the paper. With 5 outliers among 20 points a
    clean triple is drawn with probability 1 - 0.601^7 = 0.97."""

    fault_exclusion: bool = True
    """False reproduces the paper's 'no FE' ablation (Sec. 5.4): no availability detection and no
    RANSAC; the plane of all fitting points is used whenever it is geometrically defined
    (>= 3 points, not collinear). The conditioning and tilt checks below are skipped too."""

    min_sigma_m: float = 0.05
    """Floor of the factor's sigma. The paper takes Sigma_PC from the fitting residual (Sec. 4.5);
    an exact fit (e.g. 3 points) would otherwise give a near-zero sigma and an infinitely stiff
    factor."""

    sigma_model: SigmaModel = "covariance"
    """How the per-vehicle step sets the plane factor's sigma (docs/planes.md):
    "offset": hypot(fit residual floored at min_sigma_m, the offset's sigma at the centroid from the
    points' vertical sigmas averaged over distinct vehicles), the same wherever the vehicle is;
    "covariance": the fitted plane's first-order covariance (offset and the normal's two tilts,
    from the fit scatter and the points' own sigmas, correlated per vehicle) propagated to the
    vehicle's position, plus the floored residual (`coplane.plane.uncertainty`). The default since
    2026-11-29: as accurate as "offset" with a base station and more honest without one (vertical
    95 % containment 0.83 -> 0.96 on the validation urban loops; docs/tuning-plane-sigma*.md)."""

    point_error_correlation_s: float = math.inf
    """"covariance" model: correlation time of one vehicle's position errors, exp(-|dt| / this)
    between two of its points. Infinite (the default) treats all of a vehicle's points near the
    query as one error, as "offset" does; a finite value lets a vehicle's pass minutes earlier
    count as independent."""

    max_history_s: float = 600.0
    """Positions older than this (relative to the fitting epoch) are ignored and pruned: eq. (2)
    keeps 'from the beginning', which is unbounded; 600 s is far beyond a 50 m neighbourhood."""

    min_singular_ratio: float = 1.5
    """Ill-conditioning rule (not in the paper): the middle singular value s2 of the centred points
    (their lateral spread) must be at least this multiple of the smallest s3 (the scatter off the
    plane). Points from one lane lie near a line, so the cross-slope is decided by noise: with pure
    isotropic noise on 20 points s2/s3 has median 1.33 and exceeds 1.5 in ~25% of the fits (~4%
    also pass the tilt rule), while two lanes 3.5 m apart with 1 m noise pass 92% of the time.
    docs/planes.md has the sweep behind this value; 1.0 disables the rule."""

    max_tilt_deg: float | None = 8.0
    """Tilt rule (not in the paper): the plane normal must be within this angle of local up. It
    rejects 'planes' that are not roads, e.g. the vertical plane through a single-lane crest, which
    has tiny residuals. 8 deg (a 14 % grade) is above ordinary road grades but rejects planes whose
    cross-slope is noise: with lanes a few metres apart, a noisy cross-slope couples lateral
    position with height, and on the bundled recording 20 deg made `pc` worse than `mci`
    horizontally (docs/planes.md). Steep streets reach ~17 deg: raise it there; None disables."""

    cell_size_m: float = 50.0
    """Edge of the cubic ECEF cells that bucket the history (spatial index, region partitioning)."""

    max_points_per_cell: int = 4096
    """Memory bound for a crowded cell (a fleet parked in one place): once a cell holds 1.25x this
    many points it is trimmed to its newest `max_points_per_cell`."""

    time_tolerance_s: float = 1e-3
    """Times closer than this are the same epoch: 'strictly before t' excludes them, and a second
    position of one vehicle at one epoch replaces the first (a smoother's updated estimate)."""

    def __post_init__(self) -> None:
        require_finite_positive(
            self,
            ("range_fitting_m", "t_f_m", "min_sigma_m", "max_history_s", "cell_size_m", "time_tolerance_s"),
            "PlaneConfig.",
        )
        if self.sigma_model not in SIGMA_MODELS:
            raise ValueError(
                f"PlaneConfig.sigma_model must be one of {SIGMA_MODELS}, got {self.sigma_model!r}"
            )
        if not (self.point_error_correlation_s > 0.0):  # inf allowed, NaN rejected
            raise ValueError(
                f"PlaneConfig.point_error_correlation_s must be > 0, got {self.point_error_correlation_s!r}"
            )
        if self.n_min < 3:
            raise ValueError(f"PlaneConfig.n_min must be >= 3 (a plane needs 3 points), got {self.n_min}")
        if self.n_max < self.n_min:
            raise ValueError(f"PlaneConfig.n_max ({self.n_max}) < n_min ({self.n_min}): no plane could pass")
        if self.ransac_iterations < 1:
            raise ValueError(f"PlaneConfig.ransac_iterations must be >= 1, got {self.ransac_iterations}")
        if not (math.isfinite(self.min_singular_ratio) and self.min_singular_ratio >= 1.0):
            raise ValueError(f"PlaneConfig.min_singular_ratio must be >= 1, got {self.min_singular_ratio!r}")
        if self.max_tilt_deg is not None and not (0.0 < self.max_tilt_deg <= 90.0):
            raise ValueError(
                f"PlaneConfig.max_tilt_deg must be in (0, 90] or None, got {self.max_tilt_deg!r}"
            )
        if self.max_points_per_cell < self.n_max:
            raise ValueError(
                f"PlaneConfig.max_points_per_cell ({self.max_points_per_cell}) < n_max ({self.n_max})"
            )
