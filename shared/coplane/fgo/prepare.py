"""From a validated vehicle epoch to what its factors need: initial values, links, clock steps.

This is the stage between `coplane.estimation.validate_epoch` and the factors (`blocks`): it
predicts the new position from the vehicle's last state (velocity, paper eqs. 35-36; the links
themselves are built in `links`), optionally gates pseudoranges against that prediction,
initialises one clock per GNSS system (or, with `FgoConfig.clock_isb_sigma_m`, the receiver's one
clock and an offset per other system), links each clock to its previous value unless the receiver
clock jumped, and counts the independent position constraints the vehicle brings, so that a
vehicle whose first position would be indeterminate is left out instead of making the whole
cluster singular.
"""

from __future__ import annotations

import dataclasses
import functools
import statistics
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from coplane.estimation.contract import PlaneObs
from coplane.estimation.validate import ValidPseudoranges, ValidRange, ValidVehicle
from coplane.fgo import factors as F
from coplane.fgo.common_error import common_error_covariance
from coplane.fgo.config import FgoConfig
from coplane.fgo.links import (
    BiasLink,
    ClockLink,
    MotionLink,
    clock_reference,
    constant_drift,
    displacement,
    drift_step,
    inter_system_biases,
    predicted_clocks,
)
from coplane.fgo.screen import ScreenResult, clock_jumped, screen_pseudoranges, weak_rows
from coplane.fgo.state import GraphState, StepStats
from coplane.fgo.window import StateBlock
from coplane.gnss.constants import C
from coplane.gtime import GpsTime
from coplane.numeric import row_norms
from coplane.typing import Mat, Vec


@dataclass
class Prepared:
    """A vehicle epoch after preparation, before its factors exist (needed for the rank check)."""

    vid: str
    prs: ValidPseudoranges
    systems: list[str]  # those with a clock variable: every observed one, or the reference alone
    plane: PlaneObs | None
    velocity: Vec | None
    drift: float | None
    init_pos: Vec
    link: MotionLink | None
    clock_init: dict[str, float]  # system -> seconds
    clock_links: dict[str, ClockLink]
    rank_self: int  # independent position constraints of its own (pseudoranges, clock links, plane)
    # the FDE's signed standardised residual of each kept pseudorange (NaN: not tested); None
    # when the FDE did not run (no prior yet) or did not pass: the cooperative check's input
    fde_w: Vec | None = None
    restarted: bool = False  # a new track although the window holds earlier states (FgoConfig)
    bias_links: list[BiasLink] = dataclasses.field(default_factory=list)
    clock_ref: str | None = None  # the one receiver clock's system (FgoConfig.clock_isb_sigma_m)
    # ECEF covariance of the errors common to the window's epochs (`common_error`), for the report
    # only; None: not asked for (FgoConfig.covariance_common_scale 0) or not determined
    common_cov: Mat | None = None
    kernel: bool = True  # its pseudoranges take the robust kernel (`FgoConfig.robust_warmup_epochs`)
    fde_dropped: bool = False  # every pseudorange dropped by FgoConfig.fde_snapshot_dead_reckon
    excluded: tuple[str, ...] = ()  # the validated pseudoranges left out (`contract.left_out`)


def prepare_vehicle(
    v: ValidVehicle, t: GpsTime, state: GraphState, cfg: FgoConfig, stats: StepStats
) -> Prepared | str:
    """Initial values and links of one vehicle's new state, or why it cannot get one."""
    prs = v.pseudoranges
    if cfg.pseudorange_sigma_scale != 1.0:
        prs = dataclasses.replace(prs, sigma=prs.sigma * cfg.pseudorange_sigma_scale)
    plane = v.plane if cfg.use_planes else None
    velocity, spp = v.velocity, v.spp
    hist = state.window.by_vehicle.get(v.vehicle_id)
    # None: no satellite to tell by; keep what the last epoch with satellites said
    if v.doppler_observed is False:
        state.no_doppler.add(v.vehicle_id)
    elif v.doppler_observed:
        state.no_doppler.discard(v.vehicle_id)
    limit = cfg.three_state_max_pseudoranges
    three_state = limit is None or 1 <= len(prs) <= limit  # where the opt-in links may apply
    link: MotionLink | None = None
    if hist:
        last = hist[-1]
        dt = t - last.time
        p_last = state.position(last.pos_key)
        if cfg.use_velocity:
            link = displacement(hist, velocity, dt, state, cfg, three_state, v.vehicle_id in state.no_doppler)
            init = p_last + link.displacement
        elif spp is not None:
            init = spp
        else:
            init = p_last + (velocity * dt if velocity is not None else 0.0)
    elif spp is not None:
        init = spp
    else:
        return "no SPP position to initialise from" if len(prs) else "no GNSS and no state in the window"

    if hist and cfg.gate_k is not None and len(prs):
        prs = gate(prs, init, cfg.gate_k, cfg.gate_prediction_sigma_m, stats)
    fde_w: Vec | None = None
    restarted = fde_dropped = False
    age = state.step - state.track_start.get(v.vehicle_id, state.step) if hist else 0
    if hist and link is not None and cfg.fde_k is not None and len(prs) > 4:
        weak = lacks_redundancy(hist, cfg.min_fix_pseudoranges)
        n_before = len(prs)
        prs, fde_w, restart_at = screen(
            prs,
            init,
            state.cov.get(hist[-1].pos_key),
            link.sigma,
            cfg,
            stats,
            young=age < cfg.fde_warmup_epochs,
            may_restart=weak,
            clock_prior=predicted_clocks(v.vehicle_id, hist, v.drift, t, state, cfg)
            if cfg.fde_clock_prior
            else None,
        )
        fde_dropped = cfg.fde_snapshot_dead_reckon and n_before > 0 and len(prs) == 0
        if restart_at is not None and weak:
            stats.reject("track_restart")
            link, hist, init, restarted = None, None, restart_at, True  # no links to the diverged window
    dead_reckon = cfg.drop_undetermined_pseudoranges or (cfg.standstill_dead_reckoning and v.standstill)
    if cfg.unverified_sigma_scale != 1.0 and 0 < len(prs) <= 3 + len(set(prs.systems)):
        # no redundancy: whatever NLOS they hold, no test could see (FgoConfig)
        prs = dataclasses.replace(prs, sigma=prs.sigma * cfg.unverified_sigma_scale)
    if hist and dead_reckon and 0 < len(prs) < determining_count(plane, cfg):
        stats.reject("undetermined_pseudorange", len(prs))
        prs = prs.subset(np.zeros(len(prs), dtype=bool))
    systems = sorted(set(prs.systems))
    # initial clock per system: median residual at the initial position (robust to NLOS)
    clock_init: dict[str, float] = {}
    if len(prs):
        resid = prs.rho + C * prs.sat_clock - row_norms(prs.sat_pos - init)
        by_system: dict[str, list[float]] = {s: [] for s in systems}
        for s, r in zip(prs.systems, resid.tolist(), strict=True):
            by_system[s].append(r)
        # statistics.median: np.median's value, without its overhead on a dozen numbers
        clock_init = {s: statistics.median(by_system[s]) / C for s in systems}
    ref = clock_reference(hist, systems, cfg)  # one receiver clock, or one per system (None)
    clock_systems = [ref] if ref is not None else systems
    clock_links: dict[str, ClockLink] = {}
    for s in clock_systems:
        prev = next((b for b in reversed(hist) if s in b.clock_keys), None) if hist else None
        if prev is None or hist is None:
            continue
        dt = t - prev.time
        ck = prev.clock_keys[s]
        cl = constant_drift(hist, prev, s, dt, state, cfg) if v.drift is None and three_state else None
        if cl is None:
            cl = drift_step(v.vehicle_id, prev, s, v.drift, t, state, cfg)
        predicted_m = C * state.clock(ck) + cl.step_m
        if s not in clock_init:  # the reference system has no satellite now: its clock goes on
            clock_init[s] = predicted_m / C
        elif clock_jumped(C * clock_init[s], predicted_m, cl.sigma_m, cfg.clock_jump_m):
            stats.reject("clock_link")  # a receiver clock jump (e.g. 1 ms steering): restart
            continue
        clock_links[s] = cl
    # a reference from the window has a clock there, so the loop gave it a first guess
    assert ref is None or ref in clock_init
    bias_links = inter_system_biases(hist, ref, systems, clock_init, t, state, cfg) if ref is not None else []
    linked = set(clock_links) | {b.system for b in bias_links if b.prev_key is not None}
    rank = sum(max(0, prs.systems.count(s) - 1 + (1 if s in linked else 0)) for s in systems) + (
        1 if plane is not None else 0
    )
    if cfg.clock_drift_carry and v.drift is not None:
        state.drift_seen[v.vehicle_id] = (v.drift, t)
    common_cov = None
    if cfg.covariance_common_scale > 0.0:
        # an epoch that cannot determine it (few satellites) keeps the last one the window has:
        # the common errors are the slow ones, and they do not vanish with the satellites
        common_cov = common_error_covariance(prs, init, cfg.covariance_common_dgnss_m)
        if common_cov is None and hist:
            common_cov = hist[-1].common_cov
    return Prepared(
        v.vehicle_id,
        prs,
        clock_systems,
        plane,
        velocity,
        v.drift,
        init,
        link,
        {c: clock_init[c] for c in clock_systems},
        clock_links,
        rank,
        fde_w,
        restarted,
        bias_links,
        ref,
        common_cov,
        # a track's first epochs (new, restarted: no history left) go without the kernel
        kernel=cfg.robust_warmup_epochs == 0 or (bool(hist) and age >= cfg.robust_warmup_epochs),
        fde_dropped=fde_dropped,
    )


def lacks_redundancy(hist: Iterable[StateBlock], min_fix: int) -> bool:
    """Whether a vehicle's window holds an epoch without redundancy (at most `min_fix`
    pseudoranges), whose errors no test could see, so that its prediction may be the wrong one
    and a diverged track may restart. An epoch the FDE dead-reckoned on purpose
    (`FgoConfig.fde_snapshot_dead_reckon`) let no unchecked error in and does not count, unless
    three did: the prediction has then coasted long enough to be the wrong one."""
    blocks = list(hist)
    if sum(b.fde_dropped for b in blocks) >= 3:
        return True
    return any(b.n_pseudoranges <= min_fix and not b.fde_dropped for b in blocks)


def determining_count(plane: PlaneObs | None, cfg: FgoConfig) -> int:
    """How many pseudoranges a tracked vehicle's epoch needs for them to be used: a fix's
    (`min_fix_pseudoranges`, 4), one fewer with a road plane, which fixes the height.

    With fewer the epoch is dead-reckoned (`drop_undetermined_pseudoranges`): with 3 satellites the
    position along the geometry's weak direction is set by their multipath and the clock
    prediction alone, dozens of metres per metre of error, and the window takes the same biased
    geometry epoch after epoch as independent information. Clock links count as constraints here
    (they do in the determinacy check too): 3 GPS + 1 BeiDou satellite with both clocks linked fix
    a position, and dropping such epochs lost much of the vertical accuracy in the simulator's
    canyons (docs/fgo.md).
    """
    return cfg.min_fix_pseudoranges - (1 if plane is not None else 0)


def gate(
    prs: ValidPseudoranges, predicted: Vec, k: float, sigma_pred: float, stats: StepStats
) -> ValidPseudoranges:
    """Drop pseudoranges whose innovation at the predicted position exceeds k sigma."""
    resid = prs.rho + C * prs.sat_clock - row_norms(prs.sat_pos - predicted)
    sys_of = np.array(prs.systems)
    keep = np.ones(len(resid), dtype=bool)
    for s in set(prs.systems):
        idx = sys_of == s
        if int(idx.sum()) < 3:
            continue  # too few to take the clock out robustly
        innov = resid[idx] - np.median(resid[idx])
        keep[idx] = np.abs(innov) <= k * np.sqrt(prs.sigma[idx] ** 2 + sigma_pred**2)
    n_out = int((~keep).sum())
    if n_out == 0 or int(keep.sum()) < 4:
        return prs
    stats.reject("gated_pseudorange", n_out)
    return prs.subset(keep)


def screen(
    prs: ValidPseudoranges,
    predicted: Vec,
    last_cov: Mat | None,
    link_sigma: float,
    cfg: FgoConfig,
    stats: StepStats,
    young: bool = False,
    may_restart: bool = False,
    clock_prior: dict[str, tuple[float, float]] | None = None,
) -> tuple[ValidPseudoranges, Vec | None, Vec | None]:
    """The pseudoranges that pass the prior-aided FDE (`screen.py`) at the predicted position,
    their signed standardised residuals (`ScreenResult.w_signed`, None if the test did not pass)
    and, when the prediction is a diverged track's (`diverged`), where the epoch's own fit puts
    the vehicle; `young`: the track started less than `fde_warmup_epochs` ago (a looser prior,
    see FgoConfig); `may_restart`: the window holds an epoch without redundancy, so the
    prediction may be the wrong one: its snapshot is kept however far it lies, and a diverged
    track restarts (the caller's rule), as without `FgoConfig.fde_snapshot_max_chi2`;
    `clock_prior`: the receiver clocks' prediction (`links.predicted_clocks`), or None: free."""
    assert cfg.fde_k is not None
    if young and last_cov is not None:
        last_cov = last_cov * (cfg.covariance_scale**2 if cfg.fde_warmup_prior == "reported" else 1e12)
    p_pred = F.floored_covariance(
        None if last_cov is None else last_cov + np.eye(3) * link_sigma**2, cfg.fde_prior_floor_m
    )
    long_rows = None
    if cfg.fde_k_long is not None:
        long_rows = weak_rows(
            prs, cfg.fde_long_below_elevation_deg, cfg.fde_long_below_cn0_dbhz, cfg.fde_long_below_best_cn0_db
        )
    test = functools.partial(
        screen_pseudoranges,
        prs,
        predicted,
        p_pred,
        cfg.fde_k,
        k_long=cfg.fde_k_long,
        long_rows=long_rows,
        two_sided=cfg.fde_long_two_sided,
        clock_prior=clock_prior,
        clock_jump_m=cfg.clock_jump_m,
    )
    res = test(snapshot_fallback=cfg.fde_snapshot_fallback, count_exclusions=cfg.fde_reject_on_exclusions)
    if res.prediction_rejected:
        stats.reject("fde_prediction_rejected")
    limit = cfg.fde_snapshot_max_chi2
    if limit is not None and not may_restart:
        d2 = snapshot_distance2(res, p_pred)
        if d2 is not None and d2 > limit:
            # the snapshot is an NLOS-consistent subset far from a track that had redundancy
            # throughout: trust the prediction, run the prior-aided test to its end
            stats.reject("fde_snapshot_disbelieved")
            res = test(divergence_min=len(prs) + 1)
            kept = int(res.keep.sum())
            if cfg.fde_snapshot_dead_reckon and (
                kept <= cfg.min_fix_pseudoranges or len(prs) - kept > 0.5 * len(prs)
            ):
                stats.reject("fde_dead_reckoned")
                res = dataclasses.replace(res, keep=np.zeros(len(prs), dtype=bool))
    n_out = len(prs) - int(res.keep.sum())
    if n_out:
        stats.reject("fde_pseudorange", n_out)
        prs = prs.subset(res.keep)
    if cfg.fde_max_sigma_scale is not None and res.variance_factor > 1.0:
        scale = min(float(np.sqrt(res.variance_factor)), cfg.fde_max_sigma_scale)
        prs = dataclasses.replace(prs, sigma=prs.sigma * scale)
    restart_at = predicted + res.offset_m if diverged(res, p_pred, cfg) and res.offset_m is not None else None
    return prs, None if res.w_signed is None else res.w_signed[res.keep], restart_at


def diverged(res: ScreenResult, p_pred: Mat, cfg: FgoConfig) -> bool:
    """Whether a rejected prediction is a diverged track (`fde_restart_chi2`): the epoch's own fit
    lies outside the prediction's region, with the fit's covariance scaled by its a-posteriori
    variance factor (never below 1), so that an NLOS-laden canyon fit, weak or inconsistent,
    does not pass for one."""
    if cfg.fde_restart_chi2 is None:
        return False
    d2 = snapshot_distance2(res, p_pred)
    return d2 is not None and d2 > cfg.fde_restart_chi2


def snapshot_distance2(res: ScreenResult, p_pred: Mat) -> float | None:
    """The squared Mahalanobis distance of a rejected prediction's snapshot fit from the
    prediction, with both covariances (the fit's scaled by its a-posteriori variance factor,
    never below 1); None when the prediction was not rejected or the snapshot has no fit."""
    if not res.prediction_rejected or res.offset_m is None:
        return None
    assert res.offset_cov is not None
    cov = res.offset_cov * max(res.variance_factor, 1.0) + p_pred
    return float(res.offset_m @ np.linalg.solve(cov, res.offset_m))


def undetermined(preps: dict[str, Prepared], ranges: list[ValidRange]) -> list[str]:
    """Vehicles whose new position would be indeterminate (rank < 3), ranges propagating.

    A vehicle linked to its previous state is determined; otherwise count its own independent
    position constraints plus ranges to vehicles already determined, until nothing changes.
    """
    det = {v for v, p in preps.items() if p.link is not None or p.rank_self >= 3}
    changed = True
    while changed:
        changed = False
        for v in sorted(preps):
            if v in det:
                continue
            n = preps[v].rank_self + sum(
                1 for r in ranges if (r.a == v and r.b in det) or (r.b == v and r.a in det)
            )
            if n >= 3:
                det.add(v)
                changed = True
    return [v for v in sorted(preps) if v not in det]
