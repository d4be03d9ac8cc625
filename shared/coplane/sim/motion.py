"""Vehicle motion on the circuit: car following per lane, lane changes, antenna truth in ECEF.

Why a car-following model instead of scripted speeds: with M vehicles (4 for the paper's
experiment, 256 for the benchmarks) sharing two lanes, scripted speeds either collide or keep
constant gaps. The Intelligent Driver Model (Treiber, Hennecke, Helbing 2000, Phys. Rev. E 62)
gives varying, collision-free gaps with a handful of parameters. Each vehicle's desired speed is
the road's speed limit at that point (section kind; lateral acceleration limit in turns;
anticipated braking before a lower limit) times a personal factor, and speeds stay inside
5-15 m/s (docs/simulator.md, vehicles). Lane changes happen at random (Poisson) when both gaps
in the target lane are safe, with a smooth 4 s lateral transition.

Truth is the antenna phase centre: the road surface point under the car plus the antenna
height (1.4-2.1 m per vehicle, drawn once) along the road-surface normal. Velocities are exact
derivatives of the position map at the instantaneous along-track and lateral rates.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from coplane.sim.road import SECTION_KINDS, Road, Sections, enu_to_ecef_curved
from coplane.typing import AnyArray


@dataclass(frozen=True)
class MotionParams:
    """Driving behaviour. Speeds in m/s, accelerations in m/s^2."""

    speed_limit_mps: dict[str, float] = field(
        default_factory=lambda: {"open": 14.5, "medium": 12.5, "deep": 11.0, "underpass": 10.5}
    )
    turn_lateral_accel: float = 1.6  # comfortable lateral acceleration in a turn
    anticipation_decel: float = 1.0  # braking used to meet a lower limit ahead
    min_speed_mps: float = 5.0
    max_speed_mps: float = 15.0
    desired_factor: tuple[float, float] = (0.86, 1.0)
    # IDM (Treiber et al. 2000, urban values of their Table 1)
    idm_accel: float = 1.2
    idm_decel: float = 2.0
    idm_time_gap_s: float = 1.2
    idm_min_gap_m: float = 3.0
    vehicle_length_m: float = 4.5
    initial_gap_m: tuple[float, float] = (12.0, 40.0)  # bumper-to-bumper at the start
    # the fleet drives as convoys (the paper's four cars "kept close to each other"): a car ahead
    # of its convoy's centre lowers its desired speed by `cohesion` per 100 m, one behind raises it
    convoy_size: int = 8
    cohesion_per_100m: float = 0.12
    lane_change_rate_per_s: float = 1.0 / 300.0
    lane_change_duration_s: float = 4.0
    antenna_height_m: tuple[float, float] = (1.4, 2.1)
    start_s_m: float = 60.0  # front vehicle's position at the start of the warm-up
    warmup_s: float = 20.0
    dt_s: float = 0.1


@dataclass(frozen=True)
class FleetStart:
    """Per vehicle: start position (m along the loop), convoy index and desired-speed factor."""

    s_m: AnyArray
    convoy: AnyArray
    factor: AnyArray


@dataclass
class FleetTrack:
    """Per epoch (K) and vehicle (M) truth and road coordinates."""

    ids: list[str]
    times_s: AnyArray  # (K,) seconds from the first epoch
    s: AnyArray  # (K, M) arc length along the loop, in [0, L)
    y: AnyArray  # (K, M) lateral offset, + left
    speed: AnyArray  # (K, M) m/s along the path
    s_rate: AnyArray  # (K, M) ds/dt
    y_rate: AnyArray  # (K, M)
    lane: AnyArray  # (K, M) lane index (target lane during a change)
    antenna_height_m: AnyArray  # (M,)
    enu: AnyArray  # (K, M, 3)
    ecef: AnyArray  # (K, M, 3)
    vel_ecef: AnyArray  # (K, M, 3)
    heading: AnyArray  # (K, M, 2) road heading (unit East-North)
    section: AnyArray  # (K, M) index into SECTION_KINDS

    def section_names(self) -> AnyArray:
        return np.asarray(SECTION_KINDS, dtype=object)[self.section]


def speed_limit_profile(road: Road, sections: Sections, p: MotionParams, step_m: float = 1.0) -> AnyArray:
    """Desired speed (m/s) on a grid of `step_m` along the loop, with turn limits and anticipation."""
    n = math.ceil(road.length_m / step_m)
    s = np.arange(n) * step_m
    kinds = sections.index(s)
    v = np.array([p.speed_limit_mps[k] for k in SECTION_KINDS])[kinds]
    for a, b, _ in road.turns():
        _, _, k = road.frame(np.array([(a + b) / 2]))
        v_turn = math.sqrt(p.turn_lateral_accel / max(abs(float(k[0])), 1e-6))
        m = (s >= a) & (s <= b)
        v[m] = np.minimum(v[m], v_turn)
    v = np.clip(v, p.min_speed_mps / p.desired_factor[0], p.max_speed_mps)
    # backward pass (twice around: periodic) so the car brakes before a lower limit
    for _ in range(2):
        for i in range(n - 1, -1, -1):
            nxt = v[(i + 1) % n]
            v[i] = min(v[i], math.sqrt(nxt * nxt + 2.0 * p.anticipation_decel * step_m))
    return v


def simulate_motion(
    road: Road,
    sections: Sections,
    params: MotionParams,
    n_vehicles: int,
    n_epochs: int,
    interval_s: float,
    origin: tuple[float, float, float],
    rng: np.random.Generator,
    start: FleetStart | None = None,
) -> FleetTrack:
    """Drive `n_vehicles` for `n_epochs` epochs; truth sampled exactly at the epochs.

    Without `start` the fleet starts as one queue behind `start_s_m` in convoys of `convoy_size`;
    the city (coplane.sim.city) passes its platoons' positions, groups and speed factors instead.
    """
    p = params
    L = road.length_m
    m = n_vehicles
    vlim = speed_limit_profile(road, sections, p)
    grid_step = L / len(vlim)

    factor = rng.uniform(*p.desired_factor, size=m)
    h_ant = np.round(rng.uniform(*p.antenna_height_m, size=m), 3)  # mm, as written in fleet.toml
    group = np.arange(m) // max(p.convoy_size, 1) if start is None else np.asarray(start.convoy)
    n_groups = int(group.max()) + 1
    lanes = np.arange(m) % road.lanes
    # initial positions: per lane, behind each other with random gaps; lanes staggered
    s = np.zeros(m)
    gaps = rng.uniform(*p.initial_gap_m, size=m)
    per_lane = [np.flatnonzero(lanes == k) for k in range(road.lanes)]
    max_len = max(len(ix) for ix in per_lane)
    budget = 0.85 * L / max(max_len, 1)  # leave room on the ring for big fleets
    for k, ix in enumerate(per_lane):
        pos = p.start_s_m - k * 0.5 * p.initial_gap_m[0]
        for j, i in enumerate(ix):
            if j > 0:
                pos -= (
                    min(gaps[i], max(budget - p.vehicle_length_m, p.idm_min_gap_m + 2.0)) + p.vehicle_length_m
                )
            s[i] = pos
    if start is not None:  # the same draws as above were made: other streams do not shift
        s, factor = np.asarray(start.s_m, dtype=float), np.asarray(start.factor, dtype=float)
    s = np.mod(s, L)
    y = road.lane_offset(lanes)
    v = np.clip(factor * vlim[(s / grid_step).astype(int) % len(vlim)], p.min_speed_mps, p.max_speed_mps)
    lc_start = np.full(m, -1e9)
    lc_from = y.copy()
    lc_to = y.copy()

    sub = max(1, round(interval_s / p.dt_s))
    dt = interval_s / sub
    n_warm = round(p.warmup_s / dt)
    total = n_warm + (n_epochs - 1) * sub + 1
    rec = {name: np.zeros((n_epochs, m)) for name in ("s", "y", "v", "sr", "yr", "lane")}
    sqrt_ab = math.sqrt(p.idm_accel * p.idm_decel)
    t = 0.0
    for step in range(total):
        # lateral position from any ongoing lane change
        tau = np.clip((t - lc_start) / p.lane_change_duration_s, 0.0, 1.0)
        y = lc_from + (lc_to - lc_from) * (1.0 - np.cos(np.pi * tau)) / 2.0
        y_rate = np.where(
            (tau > 0.0) & (tau < 1.0),
            (lc_to - lc_from) * np.pi / (2.0 * p.lane_change_duration_s) * np.sin(np.pi * tau),
            0.0,
        )
        _, _, kappa = road.frame(s)
        g = road.profile.grade(s)
        s_rate = v / np.sqrt(1.0 + g * g) / np.maximum(1.0 - kappa * y, 0.2)
        if step >= n_warm and (step - n_warm) % sub == 0:
            k = (step - n_warm) // sub
            rec["s"][k], rec["y"][k], rec["v"][k] = s, y, v
            rec["sr"][k], rec["yr"][k], rec["lane"][k] = s_rate, y_rate, lanes
        if step == total - 1:
            break
        # leaders per lane on the ring
        gap = np.full(m, np.inf)
        dv = np.zeros(m)
        for ix in (np.flatnonzero(lanes == k) for k in range(road.lanes)):
            if len(ix) < 2:
                continue
            order = ix[np.argsort(s[ix], kind="stable")]
            lead = np.roll(order, -1)
            gap[order] = np.mod(s[lead] - s[order], L) - p.vehicle_length_m
            dv[order] = v[order] - v[lead]
        ang = 2.0 * np.pi * s / L  # convoy centre as a circular mean (the loop wraps)
        cs = np.bincount(group, np.cos(ang), n_groups)
        sn = np.bincount(group, np.sin(ang), n_groups)
        centre = np.mod(np.arctan2(sn, cs), 2.0 * np.pi) * L / (2.0 * np.pi)
        ahead_m = np.mod(s - centre[group] + L / 2.0, L) - L / 2.0
        f_eff = np.clip(factor - p.cohesion_per_100m * ahead_m / 100.0, 0.7, 1.08)
        v0 = f_eff * vlim[(s / grid_step).astype(int) % len(vlim)]
        s_star = p.idm_min_gap_m + np.maximum(0.0, v * p.idm_time_gap_s + v * dv / (2.0 * sqrt_ab))
        acc = p.idm_accel * (1.0 - (v / v0) ** 4 - (s_star / np.maximum(gap, 0.1)) ** 2)
        acc = np.maximum(acc, -3.0 * p.idm_decel)
        v = np.clip(v + acc * dt, p.min_speed_mps, p.max_speed_mps)
        s = np.mod(s + s_rate * dt, L)
        # lane changes (Poisson), only on straight road outside the underpass
        want = rng.uniform(size=m) < p.lane_change_rate_per_s * dt
        if road.lanes > 1 and np.any(want):
            kinds = sections.index(s)
            for i in np.flatnonzero(want):
                if tau[i] < 1.0 or kappa[i] != 0.0 or SECTION_KINDS[int(kinds[i])] == "underpass":
                    continue
                target = lanes[i] + (
                    1 if lanes[i] == 0 else -1 if lanes[i] == road.lanes - 1 else rng.choice([-1, 1])
                )
                others = np.flatnonzero(lanes == target)
                ahead = np.mod(s[others] - s[i], L)
                behind = np.mod(s[i] - s[others], L)
                ok_a = ahead.min() - p.vehicle_length_m if len(others) else np.inf
                ok_b = behind.min() - p.vehicle_length_m if len(others) else np.inf
                v_b = v[others[np.argmin(behind)]] if len(others) else 0.0
                if ok_a > max(12.0, 0.8 * v[i]) and ok_b > max(10.0, 1.0 * v_b):
                    lanes[i] = target
                    lc_from[i] = y[i]
                    lc_to[i] = float(road.lane_offset(target))
                    lc_start[i] = t + dt
        t += dt

    ids = [f"u{i + 1}" for i in range(m)]
    times = np.arange(n_epochs) * interval_s
    S, Y = rec["s"], rec["y"]
    H = np.broadcast_to(h_ant, S.shape)
    enu = road.antenna_enu(S, Y, H)
    lat0, lon0, h0 = origin
    ecef = enu_to_ecef_curved(enu, lat0, lon0, h0)
    d = 0.01  # s: central difference of the exact position map at the current rates
    e_plus = enu_to_ecef_curved(road.antenna_enu(S + rec["sr"] * d, Y + rec["yr"] * d, H), lat0, lon0, h0)
    e_minus = enu_to_ecef_curved(road.antenna_enu(S - rec["sr"] * d, Y - rec["yr"] * d, H), lat0, lon0, h0)
    vel = (e_plus - e_minus) / (2.0 * d)
    _, heading, _ = road.frame(S)
    return FleetTrack(
        ids=ids,
        times_s=times,
        s=S,
        y=Y,
        speed=rec["v"],
        s_rate=rec["sr"],
        y_rate=rec["yr"],
        lane=rec["lane"].astype(int),
        antenna_height_m=h_ant,
        enu=enu,
        ecef=ecef,
        vel_ecef=vel,
        heading=heading,
        section=sections.index(S),
    )
