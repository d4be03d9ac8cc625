"""The settings `bench/tune_fgo.py` compares: each variant one change to a method's defaults.

Kept apart from the script so that the other benchmarks that run variants (bench_fusion_variants,
tune_real_data, few_satellites_real, variant_epochs through `tune_fgo.apply_variant`) read the same
table.
"""

from __future__ import annotations


def _no_doppler(velocity: str, share: float) -> dict[str, object]:
    """The motion link of a receiver without Doppler (FgoConfig.no_doppler_velocity and its
    covariance share), both set, so that a variant does not depend on the current defaults."""
    return {"no_doppler_velocity": velocity, "no_doppler_velocity_covariance": share}


# Each variant changes the current defaults (ROBUST_FGO) in one respect, so every row is an
# ablation of what the methods run; "previous-defaults" is the graph before the robust defaults.
VARIANTS: dict[str, dict[str, object]] = {
    "default": {},
    "previous-defaults": {
        "solver": "lm-window",
        "fde_k": None,
        "sigma_v": 0.6,
        "motion_sigma": 2.0,
        "motion_sigma_up": 2.0,
        "range_warmup_epochs": 0,
        "covariance_scale": 1.0,
    },
    "paper-window": {"solver": "lm-window"},  # the paper's LM window + anchors instead of iSAM2
    "no-fde": {"fde_k": None},
    # a Doppler outage extrapolates the window's newest Doppler velocity, not the difference of
    # estimates (FgoConfig.motion_last_doppler); pseudoranges without redundancy loosened
    # (FgoConfig.unverified_sigma_scale)
    "last-doppler": {"motion_last_doppler": True},
    "outage-horizontal": {"outage_horizontal": True},
    "unverified-2": {"unverified_sigma_scale": 2.0},
    "unverified-3": {"unverified_sigma_scale": 3.0},
    "unverified-5": {"unverified_sigma_scale": 5.0},
    "fde-keep-on-rejected-prediction": {"fde_snapshot_fallback": False},
    "gate3-no-fde": {"fde_k": None, "gate_k": 3.0},
    "cauchy": {"robust": "cauchy"},
    "no-kernel": {"robust": None},  # the FDE alone against outliers (docs/tuning-kernel.md)
    # no kernel on a track's first epochs (docs/fgo.md, "A moving car against RTK")
    "robust-warmup-1": {"robust_warmup_epochs": 1},
    "robust-warmup-5": {"robust_warmup_epochs": 5},
    "robust-warmup-10": {"robust_warmup_epochs": 10},
    # the Huber corner in sigmas (1.345 is the usual 95 %-efficiency constant, never tuned here)
    "huber-0.5": {"robust_k": 0.5},
    "huber-0.75": {"robust_k": 0.75},
    "huber-1": {"robust_k": 1.0},
    # ... narrowed only on epochs with at least N pseudoranges ("-nN")
    "huber-0.5-n8": {"robust_k_redundant": 0.5, "robust_redundant_min": 8},
    "huber-0.5-n12": {"robust_k_redundant": 0.5, "robust_redundant_min": 12},
    "huber-0.75-n10": {"robust_k_redundant": 0.75, "robust_redundant_min": 10},
    "huber-2": {"robust_k": 2.0},
    "huber-3": {"robust_k": 3.0},
    "dcs-1": {"robust": "dcs", "robust_k": 1.0},  # switchable constraints in closed form
    "dcs-4": {"robust": "dcs", "robust_k": 4.0},
    "dcs-9": {"robust": "dcs", "robust_k": 9.0},
    "coop-3.29": {"coop_fde_k": 3.29},  # one satellite's residuals across vehicles within 50 m
    "coop-2.5": {"coop_fde_k": 2.5},
    "coop-3.29-r200": {"coop_fde_k": 3.29, "coop_fde_radius_m": 200.0},
    "huber-planes-links": {"robust_planes_links": True},  # the kernel on planes and Doppler links too
    # epochs with fewer pseudoranges than a fix dead-reckoned; the clock stepped by the last
    # measured drift without one, loosely or with a sigma growing with its age (docs/fgo.md,
    # "Few satellites on a real receiver")
    "drop-undetermined": {"drop_undetermined_pseudoranges": True},
    "carry-drift": {"clock_drift_carry": True},
    # the FDE's divergence rules (docs/fgo.md, "A diverged track comes back")
    "fde-no-restart": {"fde_restart_chi2": None},
    "fde-first-test-only": {"fde_reject_on_exclusions": False, "fde_restart_chi2": None},
    # a rejected prediction's snapshot believed only within this chi2 of the prediction
    # (FgoConfig.fde_snapshot_max_chi2; found on a city drive; alone it was vetoed by the held-out
    # seeds, with fde_snapshot_dead_reckon it is a default: docs/fgo.md "A right prediction
    # against a far snapshot")
    "snapshot-chi2-25": {"fde_snapshot_max_chi2": 25.0},
    "snapshot-chi2-50": {"fde_snapshot_max_chi2": 50.0},
    "snapshot-chi2-100": {"fde_snapshot_max_chi2": 100.0},
    "snapshot-chi2-200": {"fde_snapshot_max_chi2": 200.0},
    # ... and an epoch the prediction cannot vouch for dead-reckoned (fde_snapshot_dead_reckon)
    "snapshot-chi2-50-dr": {"fde_snapshot_max_chi2": 50.0, "fde_snapshot_dead_reckon": True},
    # the defaults without both (the snapshot always believed, as before 2026-11-30)
    "no-far-snapshot-rule": {"fde_snapshot_max_chi2": None, "fde_snapshot_dead_reckon": False},
    # the prior-aided test's clocks held to their prediction, as the EKF's gate holds its clock
    # (FgoConfig.fde_clock_prior; docs/fgo.md, "A right prediction against a far snapshot")
    "fde-clock-prior": {"fde_clock_prior": True},
    "carry-drift-wander": {"clock_drift_carry": True, "clock_drift_wander": 0.2},
    # a receiver's honest clock and motion where Doppler is missing (docs/fgo.md, "Constant
    # velocity and drift without Doppler"): the systems' clocks tied, one receiver clock and an
    # offset per other system (a random walk of 0.05 or 0.5 m per root second, chosen: 0.5); a constant
    # clock drift over the last three clocks (the EKF baselines' drift density, 0.1 m^2/s^3);
    # and with it a constant velocity over the last three positions, at white-noise
    # accelerations of 1, 0.25 and 0.0625 m^2/s^3 (the EKF baselines': 1.0, vertically 0.1);
    # "-weak": only in epochs with 1-4 pseudoranges. The bias at 0.5 is a default since
    # 2026-11-29 ("isb-0.5" then changes nothing); "no-isb" is each system's clock free again.
    "isb-0.5": {"clock_isb_sigma_m": 0.5},
    "no-isb": {"clock_isb_sigma_m": None},
    "isb-0.05": {"clock_isb_sigma_m": 0.05},
    "cv-clock": {"clock_isb_sigma_m": 0.5, "clock_accel_psd": 0.1},
    "cv-1": {
        "clock_isb_sigma_m": 0.5,
        "clock_accel_psd": 0.1,
        "motion_accel_psd": 1.0,
        "motion_accel_psd_up": 0.1,
    },
    "cv-0.25": {
        "clock_isb_sigma_m": 0.5,
        "clock_accel_psd": 0.1,
        "motion_accel_psd": 0.25,
        "motion_accel_psd_up": 0.025,
    },
    "cv-0.0625-weak": {
        "clock_isb_sigma_m": 0.5,
        "clock_accel_psd": 0.1,
        "motion_accel_psd": 0.0625,
        "motion_accel_psd_up": 0.01,
        "three_state_max_pseudoranges": 4,
    },
    "cv-0.0625": {
        "clock_isb_sigma_m": 0.5,
        "clock_accel_psd": 0.1,
        "motion_accel_psd": 0.0625,
        "motion_accel_psd_up": 0.01,
    },
    # receivers without Doppler (`--no-doppler`): a constant velocity over the last three positions
    # instead of the frozen difference of the last two, at the EKF baselines' own densities (1.0
    # horizontal, 0.1 vertical, `baselines.fleet_filter`) and at a quarter of them
    "cv-ekf": {"motion_accel_psd": 1.0, "motion_accel_psd_up": 0.1},
    "cv-ekf-quarter": {"motion_accel_psd": 0.25, "motion_accel_psd_up": 0.025},
    # and for those receivers the fallback's velocity, the difference of the last two estimates
    # (FgoConfig.no_doppler_velocity, docs/tuning-no-doppler.md); each variant on the previous
    # defaults (the 3-D difference, no covariance), as before they were chosen
    "no-doppler-estimates": _no_doppler("estimates", 0.0),
    "no-doppler-horizontal": _no_doppler("horizontal", 0.0),
    "no-doppler-none": _no_doppler("none", 0.0),
    "no-doppler-estimates-cov-1": _no_doppler("estimates", 1.0),
    "no-doppler-horizontal-cov-0.1": _no_doppler("horizontal", 0.1),
    "no-doppler-horizontal-cov-0.25": _no_doppler("horizontal", 0.25),
    "no-doppler-horizontal-cov-0.5": _no_doppler("horizontal", 0.5),
    "no-doppler-horizontal-cov-1": _no_doppler("horizontal", 1.0),
    # and the height's sigma of such a receiver (FgoConfig.no_doppler_sigma_up; m/s, every epoch)
    "no-doppler-up-0.2": {"no_doppler_sigma_up": 0.2},
    "no-doppler-up-0.3": {"no_doppler_sigma_up": 0.3},
    "no-doppler-up-0.4": {"no_doppler_sigma_up": 0.4},
    "no-doppler-up-0.5": {"no_doppler_sigma_up": 0.5},
    "no-doppler-up-0.7": {"no_doppler_sigma_up": 0.7},
    "dcs-4-planes-links": {"robust": "dcs", "robust_k": 4.0, "robust_planes_links": True},
    "sigma-v-0.05": {"sigma_v": 0.05},
    "sigma-v-0.2": {"sigma_v": 0.2},
    "sigma-v-0.3": {"sigma_v": 0.3},  # the default before the 2026-11-25 round
    "fallback-2-m/s": {"motion_sigma": 2.0, "motion_sigma_up": 2.0},  # no separate vertical bound
    "pr-sigma-x2": {"pseudorange_sigma_scale": 2.0},
    "adaptive-sigma": {"fde_max_sigma_scale": 5.0},
    "fde-prior-floor-1m": {"fde_prior_floor_m": 1.0},
    "fde-warmup-10": {"fde_warmup_epochs": 10},  # a new track's first epochs: the reported covariance
    "fde-warmup-10-snapshot": {"fde_warmup_epochs": 10, "fde_warmup_prior": "snapshot"},
    "no-range-warmup": {"range_warmup_epochs": 0},
    # the FDE's w-test with a lower threshold on the NLOS side (pseudoranges measured too long)
    "fde-long-2.5": {"fde_k_long": 2.5},
    "fde-long-2.0": {"fde_k_long": 2.0},
    "fde-long-1.5": {"fde_k_long": 1.5},
    # ... only for satellites likely NLOS: low (elevation) or weak (C/N0)
    "fde-long-2.5-cn0-38": {"fde_k_long": 2.5, "fde_long_below_cn0_dbhz": 38.0},
    "fde-long-2.0-cn0-38": {"fde_k_long": 2.0, "fde_long_below_cn0_dbhz": 38.0},
    "fde-long-2.0-cn0-35": {"fde_k_long": 2.0, "fde_long_below_cn0_dbhz": 35.0},
    "fde-long-2.0-el-30": {"fde_k_long": 2.0, "fde_long_below_elevation_deg": 30.0},
    "fde-long-1.5-cn0-35": {"fde_k_long": 1.5, "fde_long_below_cn0_dbhz": 35.0},
    "fde-long-1.5-cn0-38": {"fde_k_long": 1.5, "fde_long_below_cn0_dbhz": 38.0},
    "fde-long-1.0-cn0-35": {"fde_k_long": 1.0, "fde_long_below_cn0_dbhz": 35.0},
    "fde-long-1.5-cn0-32": {"fde_k_long": 1.5, "fde_long_below_cn0_dbhz": 32.0},
    # ... C/N0 relative to the epoch's strongest satellite (follows the receiver's levels)
    "fde-long-1.5-best-10": {"fde_k_long": 1.5, "fde_long_below_best_cn0_db": 10.0},
    "fde-long-1.5-best-12": {"fde_k_long": 1.5, "fde_long_below_best_cn0_db": 12.0},
    "fde-long-1.5-best-14": {"fde_k_long": 1.5, "fde_long_below_best_cn0_db": 14.0},
    "fde-long-2.0-best-12": {"fde_k_long": 2.0, "fde_long_below_best_cn0_db": 12.0},
    # ... on both sides of the faint satellites (cutting one tail of the clean noise biases heights)
    "fde-faint-two-sided": {
        "fde_k_long": 1.5,
        "fde_long_below_best_cn0_db": 12.0,
        "fde_long_two_sided": True,
    },
    "fde-faint-two-sided-2.0": {
        "fde_k_long": 2.0,
        "fde_long_below_best_cn0_db": 12.0,
        "fde_long_two_sided": True,
    },
    # road-height links (off by default, docs/fgo.md). The first try (docs/tuning-height-links.md)
    # had no prediction: a fixed 0.05 grade, reach 50 m (100 m), once one of the two tracks is 5
    # epochs old (from the first epoch), and with one setting changed
    "height-links": {"height_link_max_m": 50.0, "height_link_doppler_grade_sigma": 0.0},
    "height-links-100": {"height_link_max_m": 100.0, "height_link_doppler_grade_sigma": 0.0},
    "height-links-cold": {
        "height_link_max_m": 50.0,
        "height_link_settled_epochs": 0,
        "height_link_doppler_grade_sigma": 0.0,
    },
    "height-links-grade-0.1": {
        "height_link_max_m": 50.0,
        "height_link_grade": 0.1,
        "height_link_doppler_grade_sigma": 0.0,
    },
    "height-links-sigma-0.5": {
        "height_link_max_m": 50.0,
        "height_link_sigma_m": 0.5,
        "height_link_doppler_grade_sigma": 0.0,
    },
    # ... predicting the height difference from both vehicles' Doppler grades
    "height-links-doppler": {"height_link_max_m": 50.0, "height_link_doppler_grade_sigma": 0.02},
    "height-links-doppler-0.01": {"height_link_max_m": 50.0, "height_link_doppler_grade_sigma": 0.01},
    "height-links-doppler-0.04": {"height_link_max_m": 50.0, "height_link_doppler_grade_sigma": 0.04},
    "covariance-scale-3.5": {"covariance_scale": 3.5},  # the default before the 2026-11-25 round
    "no-covariance-scale": {"covariance_scale": 1.0},
    # the reported covariance: the marginal x covariance_scale^2 + the common errors' covariance x
    # covariance_common_scale^2 (fgo.common_error; docs/fgo.md "An honest covariance"). First
    # round: the term in both modes (the base station's errors as 0.75 m / sin el with DGNSS) and
    # a smaller scale on the marginal, not adopted ...
    "cov-common": {
        "covariance_scale": 1.0,
        "covariance_common_scale": 1.0,
        "covariance_common_dgnss_m": 0.75,
    },
    "cov-common-0.7": {
        "covariance_scale": 1.0,
        "covariance_common_scale": 0.7,
        "covariance_common_dgnss_m": 0.75,
    },
    "cov-common-1.4": {
        "covariance_scale": 1.0,
        "covariance_common_scale": 1.4,
        "covariance_common_dgnss_m": 0.75,
    },
    "cov-common-k1.5": {
        "covariance_scale": 1.5,
        "covariance_common_scale": 1.0,
        "covariance_common_dgnss_m": 0.75,
    },
    "cov-common-k2": {
        "covariance_scale": 2.0,
        "covariance_common_scale": 1.0,
        "covariance_common_dgnss_m": 0.75,
    },
    "cov-common-0.7-k1.5": {
        "covariance_scale": 1.5,
        "covariance_common_scale": 0.7,
        "covariance_common_dgnss_m": 0.75,
    },
    "cov-common-0.7-k2": {
        "covariance_scale": 2.0,
        "covariance_common_scale": 0.7,
        "covariance_common_dgnss_m": 0.75,
    },
    # ... second round: the broadcast atmosphere's residual alone (standalone), on the marginal's
    # scale as chosen with DGNSS
    "no-cov-atmosphere": {"covariance_common_scale": 0.0},  # the default until 2026-11-29
    "cov-atmosphere-0.5": {"covariance_common_scale": 0.5},  # the default since
    "cov-atmosphere-0.7": {"covariance_common_scale": 0.7},
    "cov-atmosphere-1": {"covariance_common_scale": 1.0},
    # iSAM2's Gauss-Newton steps per epoch: 1 + isam2_extra_iterations (fusion cost, issue 16)
    "isam2-extra-1": {"isam2_extra_iterations": 1},  # the default until 2026-11-27
    "isam2-extra-2": {"isam2_extra_iterations": 2},
    "isam2-full-check": {"isam2_partial_relinearization_check": False},  # the default until 2026-11-26
    # a new or rebuilt smoother's convergence loop: at most 3 more updates instead of 10
    "isam2-converge-3": {"isam2_converge_iterations": 3},
    # ... or until no position moves by more than this (m; default 1 mm)
    "isam2-converged-0.005": {"isam2_converged_m": 0.005},
    "isam2-converged-0.01": {"isam2_converged_m": 0.01},
    # iSAM2 relinearises a state once its estimate moved this far (m) from its linearisation point
    "isam2-relin-0.01": {"isam2_relinearize_threshold": 0.01},  # the default until 2026-11-29
    "isam2-relin-0.02": {"isam2_relinearize_threshold": 0.02},
    "isam2-relin-0.1": {"isam2_relinearize_threshold": 0.1},
    # iSAM2 marginalises and relinearises on one update in n of a cluster's smoother (default 5)
    "isam2-cycle-1": {"isam2_cycle_updates": 1},  # every update: the default until 2026-11-29
    "isam2-cycle-2": {"isam2_cycle_updates": 2},
    "isam2-cycle-3": {"isam2_cycle_updates": 3},
    "isam2-cycle-8": {"isam2_cycle_updates": 8},
    # the plane factor's sigma times this (FgoConfig.plane_sigma_scale, default 1)
    "plane-weight-0.7": {"plane_sigma_scale": 0.7},
    "plane-weight-0.5": {"plane_sigma_scale": 0.5},
    "plane-weight-1.4": {"plane_sigma_scale": 1.4},
    # a split cluster's largest part goes on with its smoother instead of every part being rebuilt
    "keep-on-split": {"isam2_keep_on_split": True},
}
# GNC needs a batch solve: compare with paper-window (the same window with Huber + FDE). About ten
# times slower than LM, so not in the default runs (docs/tuning-gnc.md, made with --seeds).
SLOW_VARIANTS: dict[str, dict[str, object]] = {
    "gnc-tls-window": {"solver": "lm-window", "robust": None, "gnc": "tls"},
    "gnc-gm-window": {"solver": "lm-window", "robust": None, "gnc": "gm"},
}
VARIANTS.update(SLOW_VARIANTS)
# The baselines' one tuned setting, the Doppler velocity's sigma (MethodSpec.velocity_sigma): its
# default (0.1, the FGO methods' sigma_v) against the paper's 0.6 and the earlier 0.3.
BASELINE_VARIANTS: dict[str, dict[str, object]] = {
    "-": {},
    "velocity-sigma-0.3": {"velocity_sigma": 0.3},
    "velocity-sigma-0.6": {"velocity_sigma": 0.6},
}
# Settings of the vehicles' plane step (PlaneConfig) for the FGO methods, each one change to its
# defaults; a run names one of these or a VARIANTS entry (docs/tuning-plane-sigma.md).
PLANE_VARIANTS: dict[str, dict[str, object]] = {
    "plane-sigma-offset": {"sigma_model": "offset"},
    "plane-sigma-covariance": {"sigma_model": "covariance"},
}
