"""What values `FgoConfig`'s settings may take: checked when a config is made, so that a bad
`--fgo name=value` or a bad method definition fails with the setting's name before any run.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Literal

from coplane.errors import require_finite_positive

if TYPE_CHECKING:
    from coplane.fgo.config import FgoConfig

Solver = Literal["lm-window", "isam2-fixed-lag", "batch-fixed-lag"]
Robust = Literal["huber", "cauchy", "dcs"]

SOLVERS: tuple[Solver, ...] = ("lm-window", "isam2-fixed-lag", "batch-fixed-lag")
ROBUST_KERNELS: tuple[Robust, ...] = ("huber", "cauchy", "dcs")
NoDopplerVelocity = Literal["estimates", "horizontal", "none"]  # FgoConfig.no_doppler_velocity
NO_DOPPLER_VELOCITIES: tuple[NoDopplerVelocity, ...] = ("estimates", "horizontal", "none")

# Usual 95 %-efficiency tuning constants (in whitened units, i.e. sigmas) when robust_k is None.
# DCS (dynamic covariance scaling, the closed form of switchable constraints): Phi = 1, the value
# its authors found to work across pose graphs; weight (2 Phi / (Phi + e^2))^2 beyond e^2 = Phi.
DEFAULT_ROBUST_K: dict[str, float] = {"huber": 1.345, "cauchy": 2.3849, "dcs": 1.0}


def check_fgo_config(cfg: FgoConfig) -> None:
    """Raise ValueError naming the first setting of `cfg` that is out of range."""
    if cfg.solver not in SOLVERS:
        raise ValueError(f"unknown solver {cfg.solver!r}; valid: {', '.join(SOLVERS)}")
    if cfg.robust is not None and cfg.robust not in ROBUST_KERNELS:
        raise ValueError(f"unknown robust kernel {cfg.robust!r}; valid: None, {', '.join(ROBUST_KERNELS)}")
    if cfg.robust_planes_links and cfg.robust is None:
        raise ValueError("robust_planes_links needs a robust kernel (robust='huber', 'cauchy' or 'dcs')")
    if cfg.gnc is not None:
        if cfg.gnc not in ("tls", "gm"):
            raise ValueError(f"unknown gnc loss {cfg.gnc!r}; valid: None, tls, gm")
        if cfg.solver != "lm-window" or cfg.robust is not None:
            raise ValueError("gnc needs solver='lm-window' and robust=None (GNC weighs the factors itself)")
        if not 0.0 < cfg.gnc_inlier_probability < 1.0:
            raise ValueError(f"gnc_inlier_probability must be in (0, 1), got {cfg.gnc_inlier_probability!r}")
    if cfg.no_doppler_velocity not in NO_DOPPLER_VELOCITIES:
        raise ValueError(
            f"unknown no_doppler_velocity {cfg.no_doppler_velocity!r}; valid: {', '.join(NO_DOPPLER_VELOCITIES)}"
        )
    if int(cfg.window_epochs) != cfg.window_epochs or cfg.window_epochs < 1:
        raise ValueError(f"window_epochs must be a positive integer, got {cfg.window_epochs!r}")
    optional = (  # thresholds checked where set (None switches each one off)
        "robust_k",
        "robust_k_redundant",
        "fde_k",
        "fde_k_long",
        "fde_long_below_elevation_deg",
        "fde_long_below_cn0_dbhz",
        "fde_long_below_best_cn0_db",
        "coop_fde_k",
        "fde_max_sigma_scale",
        "fde_restart_chi2",
        "fde_snapshot_max_chi2",
        "clock_drift_wander",
        "no_doppler_sigma_up",
        "motion_accel_psd",
        "clock_accel_psd",
        "clock_isb_sigma_m",
    )
    require_finite_positive(
        cfg,
        (
            "sigma_v",
            "plane_sigma_scale",
            "range_sigma",
            "range_warmup_max_m",
            "height_link_grade",
            "height_link_sigma_m",
            "covariance_scale",
            "clock_rw_sigma",
            "clock_drift_sigma",
            "clock_jump_m",
            "anchor_sigma",
            "motion_sigma",
            "max_speed",
            "motion_sigma_up",
            "motion_accel_psd_up",
            "max_vertical_speed",
            "lm_relative_error_tol",
            "lm_absolute_error_tol",
            "isam2_relinearize_threshold",
            "isam2_converged_m",
            *(name for name in optional if getattr(cfg, name) is not None),
            "coop_fde_radius_m",
            "fde_prior_floor_m",
            "pseudorange_sigma_scale",
        ),
    )
    if cfg.solver == "lm-window" and (cfg.motion_accel_psd is not None or cfg.clock_accel_psd is not None):
        raise ValueError(
            "motion_accel_psd and clock_accel_psd need a fixed-lag smoother (solver "
            "'isam2-fixed-lag' or 'batch-fixed-lag'): the lm-window drops a three-state link when "
            "its oldest state leaves, and the state after it is left without one"
        )
    if cfg.three_state_max_pseudoranges is not None and cfg.three_state_max_pseudoranges < 1:
        raise ValueError(
            f"three_state_max_pseudoranges must be >= 1 or None, got {cfg.three_state_max_pseudoranges!r}"
        )
    if cfg.fde_warmup_epochs < 0:
        raise ValueError(f"fde_warmup_epochs must be >= 0, got {cfg.fde_warmup_epochs!r}")
    if cfg.fde_warmup_prior not in ("reported", "snapshot"):
        raise ValueError(f"fde_warmup_prior must be 'reported' or 'snapshot', got {cfg.fde_warmup_prior!r}")
    for name in ("covariance_common_scale", "covariance_common_dgnss_m", "no_doppler_velocity_covariance"):
        value = getattr(cfg, name)
        if not (math.isfinite(value) and value >= 0):
            raise ValueError(f"{name} must be finite and >= 0, got {value!r}")
    if cfg.window_cluster_max < 0:
        raise ValueError(f"window_cluster_max must be >= 0, got {cfg.window_cluster_max!r}")
    if not (math.isfinite(cfg.height_link_max_m) and cfg.height_link_max_m >= 0):
        raise ValueError(f"height_link_max_m must be finite and >= 0, got {cfg.height_link_max_m!r}")
    if not (math.isfinite(cfg.height_link_doppler_grade_sigma) and cfg.height_link_doppler_grade_sigma >= 0):
        raise ValueError(
            "height_link_doppler_grade_sigma must be finite and >= 0, "
            f"got {cfg.height_link_doppler_grade_sigma!r}"
        )
    if cfg.height_link_settled_epochs < 0:
        raise ValueError(f"height_link_settled_epochs must be >= 0, got {cfg.height_link_settled_epochs!r}")
    if cfg.robust_redundant_min < 1:
        raise ValueError(f"robust_redundant_min must be >= 1, got {cfg.robust_redundant_min!r}")
    if cfg.robust_warmup_epochs < 0:
        raise ValueError(f"robust_warmup_epochs must be >= 0, got {cfg.robust_warmup_epochs!r}")
    if cfg.range_warmup_epochs < 0:
        raise ValueError(f"range_warmup_epochs must be >= 0, got {cfg.range_warmup_epochs!r}")
    if int(cfg.isam2_cycle_updates) != cfg.isam2_cycle_updates or cfg.isam2_cycle_updates < 1:
        raise ValueError(f"isam2_cycle_updates must be a positive integer, got {cfg.isam2_cycle_updates!r}")
    if cfg.lm_max_iterations < 1 or cfg.min_fix_pseudoranges < 1 or cfg.isam2_extra_iterations < 0:
        raise ValueError(
            "lm_max_iterations and min_fix_pseudoranges must be >= 1, isam2_extra_iterations >= 0"
        )
