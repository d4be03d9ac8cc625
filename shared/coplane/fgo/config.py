"""Configuration of the sliding-window factor-graph estimator (paper Sec. IV).

One frozen dataclass so a method (methods.py) is a value that can be compared, printed, hashed and
derived with `dataclasses.replace`; the estimator never reads globals.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from coplane.fgo.config_checks import (
    DEFAULT_ROBUST_K,
    ROBUST_KERNELS,
    SOLVERS,
    NoDopplerVelocity,
    Robust,
    Solver,
    check_fgo_config,
)

__all__ = ["DEFAULT_ROBUST_K", "ROBUST_KERNELS", "SOLVERS", "FgoConfig", "Robust", "Solver"]


@dataclass(frozen=True)
class FgoConfig:
    """Everything the estimator needs to know; defaults are the paper's proposed method (PC + IR).

    Solvers:
      - "lm-window": the paper's scheme. Each epoch the graph of the last `window_epochs` epochs
        is rebuilt (from cached factors) and solved by Levenberg-Marquardt; older states and their
        factors are simply deleted. A loose anchor prior on each vehicle's oldest state keeps the
        window observable when it holds no GNSS at all (see `anchor_sigma`).
      - "isam2-fixed-lag" / "batch-fixed-lag": GTSAM's fixed-lag smoothers with lag
        `window_epochs - 1`: states leaving the window are marginalised (their information stays as
        a prior), not deleted; iSAM2 marginalises them once per `isam2_cycle_updates` updates.
    """

    window_epochs: int = 5  # paper: l = 5 measuring cycles
    solver: Solver = "lm-window"
    use_ranging: bool = True
    use_planes: bool = True
    use_velocity: bool = True
    # The plane factor's sigma is the node's (the fit's own uncertainty at the vehicle,
    # `PlaneConfig.sigma_model`) times this: below 1 the graph weighs a plane more than its
    # uncertainty says. Studied on the training seeds and not adopted: 1 is at the optimum there,
    # 0.5 loses height accuracy (docs/planes.md, "How much a fleet plane can add").
    plane_sigma_scale: float = 1.0
    # Paper sigma_V (m/s): the velocity between factor has sigma_V * dt per axis (eqs. 35-37).
    sigma_v: float = 0.6
    # UWB ranging sigma (m) when a RangeObs carries no positive sigma (paper: 0.3 m, UWB datasheet).
    range_sigma: float = 0.3
    # A range between two vehicles both tracked for less than this many epochs since they started
    # (from their SPP) waits: a range fixes a distance, not a side, so two vehicles a few metres
    # apart whose SPP fixes are swapped stay swapped (with planes pinning the height they cannot
    # pass each other without crossing the range's barrier). A settled end anchors the range, so it
    # is not held. 0: every range from the first epoch (the paper).
    range_warmup_epochs: int = 0
    # ... only ranges shorter than this (m), and only while the two fixes' distance is within this
    # of the range: a distance well above the SPP error cannot be on the wrong side, and fixes that
    # far from their range are not a swap but a far-off fix, which the range pulls in.
    range_warmup_max_m: float = 15.0
    # Road-height links (plane methods only): two vehicles linked by a range shorter than
    # `height_link_max_m` drive on one road surface, so their antennas' heights differ by the
    # road's grade over that distance plus their antenna heights' difference: a height-only link
    # with sigma sqrt(height_link_sigma_m^2 + (height_link_grade * range)^2), the plane's
    # zeroth-order form, which needs no fitted history (a cold start, a canyon without a plane).
    # 0: off, the default: tried three times (2026-11-27, docs/fgo.md), with a fixed grade, with the
    # Doppler grades below, and with the one-sided FDE. Each won on the training seeds and cost the
    # validation dense-urban seeds 5-6 % horizontally: in a deep canyon a better height pushes the
    # NLOS biases of a fix's pseudoranges into its horizontal position. 50 m with the Doppler
    # grades is the opt-in form (`coplane eval --fgo height_link_max_m=50`).
    height_link_max_m: float = 0.0
    height_link_grade: float = 0.05
    height_link_sigma_m: float = 1.0
    # ... only once one of its ends has been tracked this many epochs (0: from the first): that
    # end's height anchors the link; two new tracks (a cold start) both have their SPP's height
    height_link_settled_epochs: int = 5
    # ... and when both vehicles' Doppler velocities give a grade (vertical over horizontal speed,
    # along each one's heading; not below 2 m/s nor above 15 %), their mean predicts the height
    # difference instead of 0, with the grade's sigma hypot(height_link_doppler_grade_sigma,
    # half the two grades' difference) in place of height_link_grade. A link with a grade at one
    # end only keeps the fixed grade. 0: no prediction (every link uses the fixed grade).
    height_link_doppler_grade_sigma: float = 0.02
    # Robust kernel on pseudorange and range factors (NLOS / multipath / UWB outliers).
    robust: Robust | None = None
    robust_k: float | None = None  # None: DEFAULT_ROBUST_K[robust]
    # ... except on the pseudoranges of a track's first this many epochs (its start or restart),
    # which the graph's FDE has no prior to screen yet and the agent's RAIM has accepted: in a
    # weak sky the kernel's optimum can lie metres from the least-squares fix, and the Doppler
    # links carry that start for tens of seconds (docs/fgo.md, "A moving car against RTK"). 0: off.
    robust_warmup_epochs: int = 0
    # ... and narrowed to this k (sigmas) on an epoch with at least `robust_redundant_min`
    # pseudoranges: a small k costs efficiency that a redundant epoch can spare and a weak one
    # cannot (docs/fgo.md, "The kernel's corner"). None: `robust_k` on every epoch.
    robust_k_redundant: float | None = None
    robust_redundant_min: int = 8
    # ... and on the plane factors and the velocity (Doppler / motion) links too: NLOS biases
    # Doppler as well, and a plane fitted across a grade change is wrong for the vehicle on it.
    robust_planes_links: bool = False
    # Graduated non-convexity (`gtsam.GncLMOptimizer`) instead of a kernel, lm-window only: the
    # pseudorange, plane and range factors are candidates, every link and prior a known inlier;
    # "tls" truncated least squares, "gm" Geman-McClure; the inlier threshold is the chi-square
    # quantile `gnc_inlier_probability` of each factor's dimension (docs/fgo.md, GNC).
    gnc: Literal["tls", "gm"] | None = None
    gnc_inlier_probability: float = 0.99
    # Every pseudorange sigma (the node's C/N0-elevation model) is multiplied by this: the model
    # describes white noise, while urban multipath and NLOS are correlated over seconds, which a
    # window or a marginal prior otherwise counts as independent information (over-confident
    # covariances, too little weight on the velocity links).
    pseudorange_sigma_scale: float = 1.0
    # Pseudoranges of an epoch that no test can check, as many as the unknowns they determine or
    # fewer (3 + one clock per system: a deep canyon's 3-5 satellites), have their sigma scaled by
    # this: a consistent NLOS subset passes unseen there, so its nominal sigma makes the window
    # overconfident in a position tens of metres off, which then holds good epochs back for many
    # seconds (dense-urban training seeds). 1: their nominal sigma. Measured and left off
    # (docs/fgo.md, "A deep-canyon start").
    unverified_sigma_scale: float = 1.0
    # Innovation gate on pseudoranges against the predicted position (previous estimate + Doppler
    # displacement), per constellation after removing the median clock residual: what an EKF's
    # chi-square gate does, here before the graph. None turns it off. Only vehicles with a state in
    # the window are gated, only systems with >= 3 satellites, and never below 4 pseudoranges.
    gate_k: float | None = None
    gate_prediction_sigma_m: float = 3.0
    # Fault detection and exclusion before the graph (`screen.py`): iterated w-test of the epoch's
    # pseudoranges against the predicted position with its covariance (the last reported
    # covariance + the displacement noise, eigenvalues floored at fde_prior_floor_m^2). None: off.
    fde_k: float | None = None
    # ... and for a pseudorange measured longer than the fit (the NLOS side): None, fde_k
    fde_k_long: float | None = None
    # fde_k_long only for satellites likely to be NLOS: below this elevation (degrees), this C/N0
    # (dB-Hz), or this many dB under the epoch's strongest satellite, where reported; all None:
    # for every satellite. A clean high strong satellite keeps the symmetric test and its 0.1 %
    # false-exclusion rate (docs/fgo.md, "One-sided FDE").
    fde_long_below_elevation_deg: float | None = None
    fde_long_below_cn0_dbhz: float | None = None
    fde_long_below_best_cn0_db: float | None = None
    # fde_k_long on both sides of those satellites' residuals, not the long side only
    fde_long_two_sided: bool = False
    fde_prior_floor_m: float = 2.0
    # Cooperative exclusion (`cooperative.py`), after each vehicle's FDE: a satellite whose FDE
    # residuals summed over the vehicles within coop_fde_radius_m exceed coop_fde_k sqrt(m) is
    # excluded at all of them (NLOS that one street gives every vehicle in it). None: off.
    coop_fde_k: float | None = None
    coop_fde_radius_m: float = 50.0
    # When most of an epoch fails against the prediction, the prediction is rejected; then test
    # the epoch on its own (snapshot RAIM) instead of keeping every pseudorange (screen.py).
    fde_snapshot_fallback: bool = False
    # ... also when the iterated test has excluded more than half of a well-observed epoch, one
    # row after another (screen.py, `count_exclusions`): a diverged track held by a tight
    # covariance otherwise keeps the few rows that agree with it and never comes back.
    fde_reject_on_exclusions: bool = False
    # ... and a rejected prediction starts the vehicle's track anew at this epoch, with no position
    # or clock link to its earlier states, whose window (and the marginal it leaves behind) holds
    # the diverged estimate, when both hold:
    # - the epoch on its own (the snapshot RAIM's fit) puts the vehicle outside the prediction's
    #   region: squared Mahalanobis distance of the two, with both covariances, above this;
    # - the window holds an epoch of the vehicle without redundancy (at most
    #   min_fix_pseudoranges pseudoranges), whose errors no test could see.
    # In the simulator's canyons a self-consistent NLOS fit lies up to 330 m (chi2 510) from a
    # prediction that is right, but above chi2 400 never after such an epoch; restarting at every
    # rejection doubled the canyons' errors (docs/fgo.md, "A diverged track comes back"). None:
    # never restart.
    fde_restart_chi2: float | None = None
    # ... and when the vehicle's window holds no epoch without redundancy (so that no error could
    # hide from the tests and the restart does not apply), a rejected prediction keeps its
    # snapshot only while the snapshot's fit lies within this squared Mahalanobis distance of the
    # prediction (the restart's measure): a deep canyon's NLOS-consistent subset lands tens of
    # metres from a prediction that is right (chi2 200-350 on a simulated city), and its rows then
    # pulled a Doppler-linked track metres off. Beyond it the epoch is screened against the
    # prediction alone, the iterated test run to its end (counted fde_snapshot_disbelieved).
    # None: always the snapshot (the bare FgoConfig's); the methods run 50 with
    # fde_snapshot_dead_reckon (`methods.registry.ROBUST_FGO`). Alone it lost the held-out seeds,
    # where stripping an epoch to 4 rows armed a restart at an NLOS fit (docs/fgo.md, "A right
    # prediction against a far snapshot").
    fde_snapshot_max_chi2: float | None = None
    # ... and where that prior-aided test then cannot keep a clear majority with redundancy (it
    # keeps at most min_fix_pseudoranges rows, or excludes more than half of the epoch), the epoch
    # has no pseudorange the prediction vouches for: it is dead-reckoned on its links (counted
    # fde_dead_reckoned) and does not count as an epoch without redundancy for the restart, unless
    # three of the window's epochs were dead-reckoned so (the prediction has coasted and may be the
    # wrong one). Without it such an epoch kept its 4 rows, which armed a restart at an NLOS fit
    # (docs/fgo.md, "A right prediction against a far snapshot"). Off in the bare FgoConfig, on
    # in ROBUST_FGO.
    fde_snapshot_dead_reckon: bool = False
    # The prior-aided test's receiver clocks held to their prediction (the last window clock
    # stepped by the drift, `links.predicted_clocks`; sigma the clock link's combined with
    # fde_prior_floor_m for the last clock's own), as the EKF's gate holds its clock, instead of free: an epoch
    # whose majority is NLOS can then no longer pull the clock to its side and strip the clean
    # rows. A system whose median residual lies beyond clock_jump_m or 5 sigma of the
    # prediction (a receiver clock jump) stays free. Opt-in, tried on the training seeds
    # (docs/fgo.md, "A right prediction against a far snapshot").
    fde_clock_prior: bool = False
    # ... and the kept pseudoranges' sigmas are scaled by sqrt(a-posteriori variance factor),
    # clipped to [1, fde_max_sigma_scale]: in a canyon the C/N0-elevation model under-states the
    # multipath the residuals show, in open sky the factor stays near 1 (None: no scaling).
    fde_max_sigma_scale: float | None = None
    # A new track starts at its SPP fix, whose graph covariance (a few metres) says nothing of the
    # NLOS that may have pulled it 20 m off in a deep canyon; screened against it, the next epochs'
    # good pseudoranges fail and the track stays wrong for tens of seconds. For this many epochs
    # after a track starts, the FDE's prior is the *reported* covariance (x covariance_scale^2,
    # the honest one) instead of the graph's; "snapshot": no prior at all (RAIM on the epoch alone).
    fde_warmup_epochs: int = 0
    fde_warmup_prior: Literal["reported", "snapshot"] = "reported"
    # Receiver clock: random walk around the Doppler clock drift (m/sqrt(s)); converted to seconds
    # for GTSAM, whose PseudorangeFactor keys the clock in seconds.
    clock_rw_sigma: float = 1.0
    # When no Doppler drift was ever measured the clock step has mean 0 and this 1-sigma drift
    # (m/s) on top: cheap TCXOs drift by up to a few hundred m/s, so this must stay loose.
    clock_drift_sigma: float = 300.0
    # Opt-in: an epoch without a Doppler drift steps the clock by the vehicle's last measured drift
    # instead of zero (`links.clock_drift`), with clock_drift_sigma or, with clock_drift_wander
    # set, a sigma growing by that much (m/s) per second since the drift was measured (capped at
    # clock_drift_sigma). Physically right, but on the real F9P and the simulator's dense-urban
    # training seeds neither form gained (docs/fgo.md, "Few satellites on a real receiver").
    clock_drift_carry: bool = False
    clock_drift_wander: float | None = None
    # Opt-in: without a Doppler drift, a system's clock with two earlier states in the window
    # keeps a constant drift over its last three values (`factors.clock_acceleration_factor`), a
    # drift random walk of this spectral density (m^2/s^3), instead of the step above.
    clock_accel_psd: float | None = None
    # A receiver's systems share one oscillator: each vehicle state has one receiver clock (the
    # first system it saw, kept while the vehicle is in the window) and each other system an
    # offset from it (metres), linked over epochs as a random walk of this sigma (m per root
    # second; `links.clock_reference`). None: each system its own clock, the paper's graph and a
    # bare FgoConfig's; the methods run 0.5 (`methods.registry.ROBUST_FGO`).
    clock_isb_sigma_m: float | None = None
    # motion_accel_psd and clock_accel_psd only for a vehicle epoch with 1 to this many
    # pseudoranges (None: every epoch), where the pseudoranges alone cannot fix it.
    three_state_max_pseudoranges: int | None = None
    # A new clock this far (m) from the predicted one (or > 5 sigma) is a receiver clock jump
    # (millisecond steering: 3e5 m): the clock link is not added, the clock restarts.
    clock_jump_m: float = 1000.0
    # lm-window only: prior on each vehicle's oldest window state at its previous estimate. Its
    # covariance is the previous marginal of that state with eigenvalues floored at anchor_sigma^2,
    # so it is negligible while GNSS is in the window and carries the vehicle through an outage
    # longer than the window, growing like dead reckoning.
    anchor_sigma: float = 10.0
    # Fallback between factor when a vehicle has no Doppler velocity at an epoch: the last known
    # velocity with sigma motion_sigma * dt (m/s) ...
    motion_sigma: float = 2.0
    # ... where the last known velocity is the newest Doppler velocity in the vehicle's window
    # (True) rather than the previous state's, else the difference of its last two estimates
    # (False), which after the first epoch of an outage also holds the smoother's corrections of
    # those estimates. Measured and left off (docs/fgo.md, "A deep-canyon start"). A receiver
    # without any Doppler has only the difference (`no_doppler_velocity`).
    motion_last_doppler: bool = False
    # ... and the fallback extrapolates only the horizontal part of that velocity, the height held
    # by `motion_sigma_up` (as `no_doppler_velocity = "horizontal"` does for receivers without
    # Doppler): the Doppler velocity of the epoch before an outage may be NLOS-struck (1.38 m/s
    # upward on a level road at a dense-urban training vehicle's canyon entrance, extrapolated
    # 13 m in 10 s). Measured and left off (docs/fgo.md, "A deep-canyon start").
    outage_horizontal: bool = False
    # ... or, if no velocity is known at all, zero with sigma max_speed * dt (m/s).
    max_speed: float = 50.0
    # A vehicle whose receiver reports no Doppler at all (an RTCM MSM4 stream, a pseudorange-only
    # log; `GraphState.no_doppler`) has no velocity but the difference of its last two estimates,
    # which the fallback above extrapolates every epoch. "estimates": that difference, as for a
    # Doppler outage (the bare default); "horizontal": without its local-up part, so that the
    # height is held by `motion_sigma_up` rather than pushed by noise (ROBUST_FGO);
    # "none": no velocity (zero with max_speed). Chosen on the training seeds recorded without
    # Doppler (docs/tuning-no-doppler.md).
    no_doppler_velocity: NoDopplerVelocity = "estimates"
    # ... and its sigma also carries this share of the two estimates' summed covariances (/ dt^2):
    # a velocity made from poorly determined positions is then a loose link, not a confident
    # extrapolation that runs away (1: the estimates' errors independent; consecutive ones are
    # correlated, so less). 0: the fallback's sigma alone (the bare default).
    no_doppler_velocity_covariance: float = 0.0
    # Opt-in: without Doppler, a vehicle with two earlier states in the window keeps a constant
    # velocity over its last three positions (`factors.acceleration_factor`), a white-noise
    # acceleration of these spectral densities (m^2/s^3, horizontal and along local up), instead
    # of the link to its last velocity frozen at that epoch's value.
    motion_accel_psd: float | None = None
    motion_accel_psd_up: float = 0.04
    # The vertical part of those fallbacks (m/s): a road vehicle's vertical speed is grade x speed
    # and changes slowly, so without Doppler the height must not get the horizontal freedom (a
    # 2 m/s vertical sigma let the height run away under a deck; 3 m/s is a 15 % grade at 72 km/h).
    motion_sigma_up: float = 0.5
    max_vertical_speed: float = 3.0
    # ... and for a receiver without any Doppler (`no_doppler_velocity`), whose height that
    # sigma holds at every epoch rather than through an outage's few: None, the same
    # `motion_sigma_up`. Held that tightly every epoch, the height lags the road's grade and
    # keeps an NLOS pull for tens of seconds (docs/fgo.md, "Receivers without Doppler").
    no_doppler_sigma_up: float | None = None
    min_fix_pseudoranges: int = 4  # has_gnss_fix threshold
    # Opt-in: a tracked vehicle's epoch with fewer pseudoranges than a fix needs
    # (min_fix_pseudoranges, one fewer with a plane; `prepare.determining_count`) adds none of them
    # and is carried by its Doppler / motion link. On a static F9P thinned to 3 satellites it keeps
    # the estimate within 5.2 m where it ran up to 65 m away, but on a moving car dead reckoning
    # without Doppler went further still (151 m against 62-137 m), and on the simulator's canyons
    # it cost `non-cp` 1-2 % (docs/fgo.md, "Few satellites on a real receiver"). Off by default.
    drop_undetermined_pseudoranges: bool = False
    # The same, only for an epoch whose velocity is the front end's detected standstill
    # (coplane.gnss.standstill): a standing vehicle is exactly what dead reckoning predicts.
    standstill_dead_reckoning: bool = True
    # The reported 3x3 covariance is the marginal x this factor^2 (the estimator's own use of it,
    # anchors and the FDE prior, is not scaled). The graph treats urban multipath as white noise
    # while it is correlated over tens of seconds, so the marginal is over-confident; 1.0 reports
    # it as it is.
    covariance_scale: float = 1.0
    # ... plus this factor^2 x the covariance of the errors common to the window's epochs
    # (`fgo.common_error`: the broadcast atmosphere's residual, which DGNSS cancels), which the
    # white-noise marginal averages away; 0: not added.
    covariance_common_scale: float = 0.0
    # With DGNSS, model what the base station leaves as this zenith sigma (m) / sin(elevation) in
    # that term; 0: not modelled there (covariance_scale, chosen with DGNSS, covers it). Tried
    # at 0.75 m with covariance_scale 1-2 and not adopted (docs/fgo.md, "An honest covariance").
    covariance_common_dgnss_m: float = 0.0
    compute_covariance: bool = True
    # Solve each connected cluster (vehicles linked by ranges in the window) on its own.
    split_clusters: bool = True
    # At most this many vehicles in one cluster of the window (0: no bound). The fusion step bounds
    # each epoch's clusters to 16 (`steps.fusion.bounded_ranges`), but as peers change within the
    # window the union of its epochs still grew: in a 256-vehicle city to 20 vehicles at the median
    # of the rebuilt clusters and 112 at most, and rebuilding smoothers over such clusters cost
    # over a third of the estimator's time. A new range that would join two window clusters beyond
    # this is left out (counted `range_cluster_bound`); a fleet within the bound keeps every range,
    # bit for bit. Chosen on the 256-vehicle city of seed 11: 16 cut the cost by 17 % but lost 31 %
    # of the horizontal accuracy, 32 cut it by 13 % at the same accuracy (docs/performance-scale.md,
    # "Window clusters", with seed 12 as the report).
    window_cluster_max: int = 32
    # Levenberg-Marquardt (lm-window and batch-fixed-lag).
    lm_max_iterations: int = 50
    lm_relative_error_tol: float = 1e-6
    lm_absolute_error_tol: float = 1e-6
    # iSAM2: relinearisation threshold in metres (a clock's, in seconds, is this over c:
    # `keys.relinearize_thresholds`). 0.05 since 2026-11-29 (0.01 before): the same accuracy on the
    # training seeds (docs/tuning-isam2.md) and on the seed-11 city, at 7 % less fusion CPU there;
    # 0.1 lost a fifth of that city's horizontal accuracy (docs/performance-scale.md, "iSAM2
    # variants on cities"). Then the number of extra update() iterations per epoch (iSAM2
    # does one Gauss-Newton step per update; 1 and 2 compared on the training seeds in
    # docs/tuning-isam2.md: since the clocks' threshold none is within 0.07 m of 1, and 1 costs 1.18
    # times none on the cities at the same accuracy; 1 was the default until 2026-11-27, docs/fgo.md).
    isam2_relinearize_threshold: float = 0.05
    isam2_extra_iterations: int = 0
    # ... and, when a smoother is (re)built or a vehicle starts from its SPP, up to this many more
    # until no position moves by more than isam2_converged_m.
    isam2_converge_iterations: int = 10
    isam2_converged_m: float = 1e-3
    # iSAM2's relinearisation check only in the part of the Bayes tree an update touches
    # (ISAM2Params.enablePartialRelinearizationCheck): the full check costs 2-3 % more fusion CPU on
    # the cities at the same accuracy there and on the training seeds (docs/tuning-isam2.md,
    # docs/performance-scale.md "iSAM2 variants on cities").
    isam2_partial_relinearization_check: bool = True
    # iSAM2 marginalises the states leaving the window and relinearises on every this-many-th
    # update of a cluster's smoother only (`smoother.SmootherCluster._update`). Either one makes it
    # re-eliminate the whole Bayes tree (an epoch moves most of a city's window states beyond the
    # relinearisation threshold), where the updates in between re-eliminate the newest epochs
    # only. The smoother then holds up to this many - 1 epochs beyond the window before it
    # marginalises them together, and a new epoch's robust weights wait as long for their
    # relinearisation. 5 since 2026-11-29 (1 before): 14 % less fusion CPU on the training city at
    # the same accuracy there, on the training seeds and on the real sets (docs/tuning-isam2.md,
    # docs/performance-scale.md "iSAM2 variants on cities").
    isam2_cycle_updates: int = 5
    # When a cluster splits, its largest part goes on with its smoother and only the others are
    # rebuilt from the window (`slots.keepers`); off: every part is rebuilt. Opt-in: on the
    # 1000-vehicle training city it saved 3 % of the fusion CPU and lost 4 % of the horizontal
    # accuracy, since a rebuilt smoother converges afresh where a kept one goes on with its
    # linearisation (docs/performance-scale.md, "Smoothers kept on a split").
    isam2_keep_on_split: bool = False

    def __post_init__(self) -> None:
        check_fgo_config(self)

    @property
    def lag(self) -> float:
        """Fixed-lag smoother lag in epoch-index units: keeps `window_epochs` epochs (iSAM2: at
        least, and up to `isam2_cycle_updates` - 1 more until its next marginalisation)."""
        return float(self.window_epochs - 1)

    @property
    def robust_tuning(self) -> float | None:
        if self.robust is None:
            return None
        return self.robust_k if self.robust_k is not None else DEFAULT_ROBUST_K[self.robust]

    def pseudorange_tuning(self, n_pseudoranges: int) -> float | None:
        """The kernel's k on an epoch with this many pseudoranges (`robust_k_redundant`)."""
        narrow = self.robust_k_redundant is not None and n_pseudoranges >= self.robust_redundant_min
        return self.robust_k_redundant if narrow and self.robust is not None else self.robust_tuning
