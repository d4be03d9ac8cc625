"""Links of a vehicle's new state to its earlier ones: motion (Doppler velocity, paper eqs. 35-36,
or the fallbacks without it) and receiver clocks (drift steps, constant drift, inter-system bias).

`prepare` decides per vehicle epoch which of these it gets; `blocks` turns them into factors.
The three-state forms (constant velocity, constant drift; FgoConfig `motion_accel_psd`,
`clock_accel_psd`) are opt-ins; one receiver clock with an offset per other system
(`clock_isb_sigma_m`) is on in the methods' defaults (docs/fgo.md).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from coplane.fgo.config import FgoConfig
from coplane.fgo.config_checks import NoDopplerVelocity
from coplane.fgo.factors import clock_step_sigma_m
from coplane.fgo.state import GraphState
from coplane.fgo.window import StateBlock
from coplane.geo import up_vector
from coplane.gnss.constants import C
from coplane.gtime import GpsTime
from coplane.typing import Vec

BIAS_SIGMA_FLOOR_M = 1e-3  # a bias link's least sigma (m): two states at one time stay solvable


@dataclass
class MotionLink:
    """The inter-epoch position factor of a new state: velocity (eq. 36) or motion fallback."""

    prev_key: int
    prev_step: int
    displacement: Vec
    sigma: float
    kind: str  # "velocity" | "motion"
    sigma_up: float | None = None  # a tighter vertical sigma (m) for the motion fallback
    # the constant-velocity form of the fallback (`FgoConfig.motion_accel_psd`), else None
    accel: AccelTerms | None = None


@dataclass(frozen=True)
class AccelTerms:
    """What `factors.acceleration_factor` needs beyond the last state: the one before it, the two
    intervals and the velocity change's sigmas (m/s)."""

    prev2_key: int
    dt0: float
    dt1: float
    sigma_mps: float
    sigma_up_mps: float | None = None  # positions only: the sigma along local up


@dataclass
class ClockLink:
    """Receiver clock random walk to the vehicle's last clock of the same system."""

    prev_key: int
    prev_step: int
    step_m: float  # mean change (Doppler drift x dt), metres
    sigma_m: float
    # the constant-drift form without Doppler (`FgoConfig.clock_accel_psd`), else None
    accel: AccelTerms | None = None


@dataclass
class BiasLink:
    """A system's offset from the vehicle's one receiver clock, a variable of its own (metres,
    `factors.pseudorange_factors`: c (dt_ref - dt_s)): held at the same offset of the
    vehicle's latest window state that had one against the same receiver clock (`prev_key`, a
    random walk of `sigma_m`), else started from the clocks' first guesses."""

    system: str
    init_m: float
    prev_key: int | None
    prev_step: int
    sigma_m: float


def displacement(
    hist: deque[StateBlock],
    velocity: Vec | None,
    dt: float,
    state: GraphState,
    cfg: FgoConfig,
    three_state: bool = True,
    no_doppler: bool = False,
) -> MotionLink:
    """Eq. 35-36 displacement to the previous state, or the motion fallback without Doppler.

    Both Doppler velocities known: their mean (exact for constant acceleration); only the new
    one: v_t * dt (the paper). No Doppler now: the last known velocity (Doppler of the previous
    state, or of the newest state with one with `motion_last_doppler`, else the difference of the
    last two estimates) with sigma motion_sigma * dt, else
    zero with sigma max_speed * dt; the fallbacks' vertical sigma is bounded by what a road allows
    (`motion_sigma_up`, `max_vertical_speed`). `no_doppler`: the receiver gives no Doppler at all,
    so the difference of estimates is all it ever has (`FgoConfig.no_doppler_velocity`).
    """
    last = hist[-1]
    if velocity is not None:
        v = 0.5 * (velocity + last.velocity) if last.velocity is not None else velocity
        return MotionLink(last.pos_key, last.step, v * dt, cfg.sigma_v * dt, "velocity")
    v_last: Vec | None = last.velocity
    if v_last is None and cfg.motion_last_doppler and not no_doppler:
        v_last = next((b.velocity for b in reversed(hist) if b.velocity is not None), None)
    var_h = var_up = 0.0  # the variance (m^2/s^2) of a velocity made from two estimates
    mode: NoDopplerVelocity = cfg.no_doppler_velocity if no_doppler else "estimates"
    one_track = len(hist) >= 2 and in_track(hist[-2], state)
    if v_last is None and one_track and mode != "none":
        prev = hist[-2]
        dt0 = last.time - prev.time
        v_last = (state.position(last.pos_key) - state.position(prev.pos_key)) / dt0
        if no_doppler:
            v_last, var_h, var_up = _estimated_velocity(v_last, last, prev, dt0, mode, state, cfg)
    if v_last is not None and cfg.outage_horizontal and not no_doppler:
        u = up_vector(state.position(last.pos_key))
        v_last = v_last - float(v_last @ u) * u  # the height is the fallback's vertical sigma's
    if three_state and cfg.motion_accel_psd is not None and one_track and last.time - hist[-2].time > 0:
        return constant_velocity(hist, dt, state, cfg)
    if v_last is not None:
        sigma = math.sqrt(cfg.motion_sigma**2 + var_h) * dt
        up = (
            cfg.no_doppler_sigma_up
            if no_doppler and cfg.no_doppler_sigma_up is not None
            else cfg.motion_sigma_up
        )
        sigma_up = math.sqrt(up**2 + var_up) * dt
        return MotionLink(last.pos_key, last.step, v_last * dt, sigma, "motion", min(sigma, sigma_up))
    sigma, sigma_up = cfg.max_speed * dt, cfg.max_vertical_speed * dt
    return MotionLink(last.pos_key, last.step, np.zeros(3), sigma, "motion", min(sigma, sigma_up))


def in_track(block: StateBlock, state: GraphState) -> bool:
    """Whether a window state belongs to its vehicle's current track. A track the FDE restarted
    (it found it diverged) keeps the diverged states in its window, but a difference across the
    restart is its jump, not a velocity or a drift: extrapolated every epoch, it carried a receiver
    without Doppler thousands of kilometres (docs/fgo.md, "Receivers without Doppler")."""
    return state.track_start.get(block.vehicle_id, -1) <= block.step


def _estimated_velocity(
    v: Vec,
    last: StateBlock,
    prev: StateBlock,
    dt0: float,
    mode: NoDopplerVelocity,
    state: GraphState,
    cfg: FgoConfig,
) -> tuple[Vec, float, float]:
    """A receiver without Doppler: the velocity between its last two estimates, horizontal only
    when `mode` says so, and its variance (m^2/s^2, horizontal per axis and up) from their
    reported covariances (`FgoConfig.no_doppler_velocity_covariance`; 0 where either is unknown).

    Why: that velocity is extrapolated every epoch, and where the estimates are poor (a deep
    canyon, few satellites) a confident extrapolation feeds its own error forward. On the dense
    city recorded without Doppler the frozen 3-D difference ran vehicles kilometres away
    (docs/tuning-no-doppler.md)."""
    share = cfg.no_doppler_velocity_covariance
    c1, c0 = state.cov.get(last.pos_key), state.cov.get(prev.pos_key)
    loosen = share > 0 and c1 is not None and c0 is not None
    if mode == "estimates" and not loosen:
        return v, 0.0, 0.0  # as for a Doppler outage: nothing to do
    u = up_vector(state.position(last.pos_key))
    if mode == "horizontal":
        v = v - float(v @ u) * u
    if not loosen:
        return v, 0.0, 0.0
    assert c1 is not None and c0 is not None  # for mypy: `loosen` says so
    cv = share * (c1 + c0) / (dt0 * dt0)
    up = float(u @ cv @ u)
    var_h = max(0.0, 0.5 * (float(np.trace(cv)) - up))
    return v, var_h, up if mode == "estimates" else 0.0  # horizontal: nothing extrapolated up


def constant_velocity(hist: deque[StateBlock], dt: float, state: GraphState, cfg: FgoConfig) -> MotionLink:
    """The constant-velocity fallback over the last two states and the new one: the link dies
    with the older of the two (`prev_step`), and its displacement (the prediction, and the FDE's
    prior sigma) is the velocity between their estimates."""
    assert cfg.motion_accel_psd is not None
    last, prev = hist[-1], hist[-2]
    dt0 = last.time - prev.time
    v = (state.position(last.pos_key) - state.position(prev.pos_key)) / dt0
    span = 0.5 * (dt0 + dt)
    s_h = math.sqrt(cfg.motion_accel_psd * span)
    s_up = min(s_h, math.sqrt(cfg.motion_accel_psd_up * span))
    accel = AccelTerms(prev.pos_key, dt0, dt, s_h, s_up)
    return MotionLink(last.pos_key, prev.step, v * dt, s_h * dt, "motion", s_up * dt, accel)


def constant_drift(
    hist: deque[StateBlock], prev: StateBlock, system: str, dt: float, state: GraphState, cfg: FgoConfig
) -> ClockLink | None:
    """The constant-drift clock link (`FgoConfig.clock_accel_psd`) over the system's last two
    clocks in the window and the new one, or None when it is off or there are not two; its step
    (the prediction) is the drift between their estimates."""
    if cfg.clock_accel_psd is None:
        return None
    prev2 = next((b for b in reversed(hist) if system in b.clock_keys and b.step < prev.step), None)
    if prev2 is None or not in_track(prev2, state) or prev.time - prev2.time <= 0:
        return None
    dt0 = prev.time - prev2.time
    k1, k0 = prev.clock_keys[system], prev2.clock_keys[system]
    drift = C * (state.clock(k1) - state.clock(k0)) / dt0
    sigma = math.sqrt(cfg.clock_accel_psd * 0.5 * (dt0 + dt))
    return ClockLink(k1, prev2.step, drift * dt, sigma * dt, AccelTerms(k0, dt0, dt, sigma))


def clock_drift(
    vid: str, drift: float | None, prev_drift: float | None, t: GpsTime, state: GraphState, cfg: FgoConfig
) -> tuple[float, float]:
    """The clock drift (m/s) to step a vehicle's receiver clock by, and its 1-sigma (m/s).

    With this epoch's Doppler drift: the mean of it and the previous state's (exact for a linear
    drift), sigma 0. Without one (fewer than 5 Doppler measurements, as in a canyon): zero with
    `clock_drift_sigma`, or with `clock_drift_carry` the vehicle's last measured drift, with that
    sigma or, when `clock_drift_wander` is set, a sigma growing with the drift's age up to it.
    docs/fgo.md ("Few satellites on a real receiver") has why carrying is not the default.
    """
    if drift is not None:
        return (0.5 * (drift + prev_drift) if prev_drift is not None else drift), 0.0
    seen = state.drift_seen.get(vid) if cfg.clock_drift_carry else None
    if seen is None:
        return 0.0, cfg.clock_drift_sigma
    last, at = seen
    if cfg.clock_drift_wander is None:
        return last, cfg.clock_drift_sigma
    return last, min(cfg.clock_drift_sigma, cfg.clock_drift_wander * max(t - at, 0.0))


def clock_reference(hist: deque[StateBlock] | None, systems: list[str], cfg: FgoConfig) -> str | None:
    """The system whose clock variable is the vehicle's one receiver clock
    (`FgoConfig.clock_isb_sigma_m`): the reference of its latest window state that had one, so the
    clock goes on through epochs without that system's satellites; else the first system seen.
    None when the systems keep clocks of their own, or the epoch has no pseudorange."""
    if cfg.clock_isb_sigma_m is None or not systems:
        return None
    prev = next((b.clock_ref for b in reversed(hist) if b.clock_ref is not None), None) if hist else None
    return prev if prev is not None else systems[0]


def inter_system_biases(
    hist: deque[StateBlock] | None,
    ref: str,
    systems: list[str],
    clock_init: dict[str, float],
    t: GpsTime,
    state: GraphState,
    cfg: FgoConfig,
) -> list[BiasLink]:
    """The offsets of a new state's systems other than the reference (`clock_ref`; m per root
    second of random walk, `FgoConfig.clock_isb_sigma_m`), each linked to its last value in the
    window. `clock_init` has every system's first guess (seconds), the reference's included."""
    assert cfg.clock_isb_sigma_m is not None
    links = []
    for s in systems:
        if s == ref:
            continue
        prev = (
            next((b for b in reversed(hist) if b.clock_ref == ref and s in b.bias_keys), None)
            if hist
            else None
        )
        if prev is None:
            links.append(BiasLink(s, C * (clock_init[ref] - clock_init[s]), None, -1, 0.0))
            continue
        k = prev.bias_keys[s]
        sigma = max(cfg.clock_isb_sigma_m * math.sqrt(max(t - prev.time, 0.0)), BIAS_SIGMA_FLOOR_M)
        links.append(BiasLink(s, state.clock(k), k, prev.step, sigma))
    return links


def drift_step(
    vid: str,
    prev: StateBlock,
    system: str,
    drift: float | None,
    t: GpsTime,
    state: GraphState,
    cfg: FgoConfig,
) -> ClockLink:
    """The receiver clock's step from `prev`'s clock of `system` to time `t` by the clock drift
    (`clock_drift`), with its sigma: the graph's clock link, and the FDE's clock prediction."""
    dt = t - prev.time
    mean, drift_sigma = clock_drift(vid, drift, prev.clock_drift_mps, t, state, cfg)
    return ClockLink(
        prev.clock_keys[system], prev.step, mean * dt, clock_step_sigma_m(dt, drift_sigma, cfg.clock_rw_sigma)
    )


def predicted_clocks(
    vid: str, hist: deque[StateBlock], drift: float | None, t: GpsTime, state: GraphState, cfg: FgoConfig
) -> dict[str, tuple[float, float]]:
    """Each system's receiver clock (m) predicted from the vehicle's latest window state, stepped
    by the clock drift (`clock_drift`), and its 1-sigma: the step's, with the latest clock's own
    uncertainty taken as `fde_prior_floor_m` (the window's clock marginals are not kept), plus
    the inter-system offset's walk for a system held by an offset (`clock_isb_sigma_m`). For the
    prior-aided FDE (`FgoConfig.fde_clock_prior`); the graph's own clock links are built apart."""
    last = hist[-1]
    out = {}
    for s, k in last.clock_keys.items():
        step = drift_step(vid, last, s, drift, t, state, cfg)
        out[s] = (C * state.clock(k) + step.step_m, math.hypot(step.sigma_m, cfg.fde_prior_floor_m))
    if last.clock_ref is not None and last.clock_ref in out:
        ref_m, ref_sigma = out[last.clock_ref]
        walk = (cfg.clock_isb_sigma_m or 0.0) * math.sqrt(max(t - last.time, 0.0))
        for s, k in last.bias_keys.items():  # bias = c (dt_ref - dt_s)
            out[s] = (ref_m - state.clock(k), math.hypot(ref_sigma, walk))
    return out
