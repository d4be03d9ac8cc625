"""A small synthetic fleet for the factor-graph tests and benchmark (deterministic by seed).

Satellites at GNSS orbit radii (GPS ~26,560 km, BeiDou MEO ~27,900 km) moving at ~3 km/s; vehicles
driving in lanes on a tilted road plane near Beijing (the paper's test area); per-vehicle GPS clock
with drift and a BeiDou inter-system bias; pseudoranges with a known sigma, optional biased "NLOS"
satellites; Doppler-like velocities; UWB ranges; exact antenna planes. The satellite positions are
handed out as the inputs contract says (already in the reception ECEF frame): the truth pseudorange
is simply |p - s| + c (b_sys - b_sat).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from coplane.estimation.contract import (
    EpochInput,
    FleetSolution,
    PlaneObs,
    PseudorangeObs,
    RangeObs,
    VehicleEpochInput,
    VelocityObs,
)
from coplane.fgo.config import FgoConfig
from coplane.geo import enu_rotation, geodetic_to_ecef
from coplane.gnss.constants import C
from coplane.gtime import GpsTime

Vec = NDArray[np.float64]

REF_LAT = math.radians(39.98)
REF_LON = math.radians(116.32)
REF_H = 50.0
ORBIT_RADIUS = {"G": 26_560e3, "C": 27_906e3}


@dataclass
class SyntheticFleet:
    epochs: list[EpochInput]
    truth: list[dict[str, Vec]]  # per epoch: vehicle -> true antenna ECEF position
    ref_ecef: Vec
    enu: NDArray[np.float64]  # rows E, N, U at the reference point
    vehicle_ids: list[str]
    nlos: dict[str, set[str]] = field(default_factory=dict)  # vehicle -> NLOS satellites

    def enu_error(self, k: int, vid: str, p: Vec) -> Vec:
        return self.enu @ (np.asarray(p) - self.truth[k][vid])


@dataclass(frozen=True)
class _Sat:
    sat: str
    pos0: Vec
    vel: Vec
    clock_s: float


def _satellites(
    rng: np.random.Generator, ref: Vec, rot: NDArray[np.float64], n_gps: int, n_bds: int
) -> list[_Sat]:
    sats: list[_Sat] = []
    for system, n in (("G", n_gps), ("C", n_bds)):
        radius = ORBIT_RADIUS[system]
        az0 = rng.uniform(0, 2 * math.pi)
        for i in range(n):
            # spread azimuths, elevations between 15 and 85 degrees
            az = az0 + 2 * math.pi * (i + rng.uniform(-0.25, 0.25)) / max(n, 1)
            el = math.radians(rng.uniform(15.0, 85.0))
            u_enu = np.array([math.cos(el) * math.sin(az), math.cos(el) * math.cos(az), math.sin(el)])
            u = rot.T @ u_enu
            # |ref + r u| = radius
            b = float(ref @ u)
            r = -b + math.sqrt(b * b - (float(ref @ ref) - radius * radius))
            pos = ref + r * u
            tangent = np.cross(pos, rng.normal(size=3))
            vel = 3000.0 * tangent / np.linalg.norm(tangent)
            sats.append(_Sat(f"{system}{i + 1:02d}", pos, vel, float(rng.uniform(-1e-4, 1e-4))))
    return sats


def _road_frame(
    heading_deg: float, slope: float, crossfall: float, rot: NDArray[np.float64]
) -> tuple[Vec, Vec, Vec]:
    """Unit along-road, left-of-road and upward-normal vectors (ECEF) of a tilted road plane."""
    h = math.radians(heading_deg)
    t = np.array([math.sin(h), math.cos(h), slope])
    t /= np.linalg.norm(t)
    left = np.array([-math.cos(h), math.sin(h), crossfall])
    left -= (left @ t) * t
    left /= np.linalg.norm(left)
    n = np.cross(t, left)
    if n[2] < 0:
        n = -n
    return rot.T @ t, rot.T @ left, rot.T @ n


def _spp(prs: Sequence[PseudorangeObs], x0: Vec) -> Vec | None:
    """Plain Gauss-Newton single-point position (one clock per system) as the initial guess."""
    systems = sorted({p.system for p in prs})
    if len(prs) < 3 + len(systems):
        return None
    x = np.concatenate([x0, np.zeros(len(systems))])
    sats = np.array([p.sat_pos_m for p in prs])
    rho = np.array([p.rho_m + C * p.sat_clock_s for p in prs])
    col = np.array([3 + systems.index(p.system) for p in prs])
    for _ in range(10):
        d = x[:3] - sats
        r = np.linalg.norm(d, axis=1)
        h = np.zeros((len(prs), x.size))
        h[:, :3] = d / r[:, None]
        h[np.arange(len(prs)), col] = 1.0
        res = rho - (r + x[col])
        dx = np.linalg.lstsq(h, res, rcond=None)[0]
        x += dx
        if np.linalg.norm(dx[:3]) < 1e-4:
            break
    return x[:3].copy()


def make_fleet(
    n_vehicles: int = 4,
    n_epochs: int = 40,
    *,
    seed: int = 0,
    dt: float = 1.0,
    n_gps: int = 8,
    n_bds: int = 6,
    pr_sigma: float = 3.0,
    nlos_per_vehicle: int = 0,
    nlos_bias: tuple[float, float] = (15.0, 40.0),
    plane_sigma: float = 0.1,
    with_planes: bool = True,
    range_sigma: float = 0.3,
    max_range: float = 500.0,
    velocity_sigma: float = 0.05,
    group_size: int = 8,
    group_spacing: float = 3000.0,
    outages: Mapping[str, range] | None = None,
    absent: Mapping[str, range] | None = None,
    sat_limit: Mapping[tuple[str, int], int] | None = None,
    clock_jumps: Mapping[str, int] | None = None,
    start_tow: float = 345_600.0,
) -> SyntheticFleet:
    """A fleet of `n_vehicles` ("v01", ...) in groups of `group_size` on their own tilted roads.

    outages: vehicle -> epochs with no GNSS at all (no pseudoranges, velocity, SPP, clock drift);
    absent: vehicle -> epochs where the vehicle sends nothing (not in EpochInput);
    sat_limit: (vehicle, epoch) -> keep only that many satellites;
    clock_jumps: vehicle -> epoch from which its receiver clock is 1 ms ahead (clock steering).
    """
    rng = np.random.default_rng(seed)
    outages = outages or {}
    absent = absent or {}
    sat_limit = sat_limit or {}
    clock_jumps = clock_jumps or {}
    ref = geodetic_to_ecef(REF_LAT, REF_LON, REF_H)
    rot = enu_rotation(REF_LAT, REF_LON)
    sats = _satellites(rng, ref, rot, n_gps, n_bds)
    ids = [f"v{i + 1:02d}" for i in range(n_vehicles)]

    # vehicles: groups on their own road plane, two lanes, ~25 m apart
    n_groups = (n_vehicles + group_size - 1) // group_size
    roads = []
    for g in range(n_groups):
        ang = 2 * math.pi * g / max(n_groups, 1)
        ring = group_spacing * math.sqrt(g)  # spread groups on a spiral, far apart
        origin = ref + rot.T @ np.array([ring * math.cos(ang * 2.4), ring * math.sin(ang * 2.4), 0.0])
        frame = _road_frame(rng.uniform(0, 360), rng.uniform(-0.04, 0.04), rng.uniform(-0.02, 0.02), rot)
        roads.append((origin, *frame))
    # a group drives together (same speed profile, tiny offsets): no overtaking, so two vehicles
    # never pass through each other and ranges stay above ~3 m
    group_speed = [
        (rng.uniform(8.0, 12.0), rng.uniform(0.5, 2.0), rng.uniform(0, 2 * math.pi)) for _ in roads
    ]
    veh: dict[str, dict[str, float | int]] = {}
    for i, vid in enumerate(ids):
        g, j = divmod(i, group_size)
        v0, amp, phase = group_speed[g]
        veh[vid] = {
            "road": g,
            "s0": -25.0 * (j // 2) + rng.uniform(-2, 2),
            "lane": 3.5 * (j % 2),
            "h": rng.uniform(1.5, 2.0),
            "v0": v0 + rng.uniform(-0.03, 0.03),
            "amp": amp,
            "phase": phase,
            "b0": rng.uniform(-3e4, 3e4),  # m
            "drift": rng.uniform(-100.0, 100.0),  # m/s
            "isb": rng.uniform(-50.0, 50.0),  # m, BDS - GPS
        }
    nlos: dict[str, set[str]] = {}
    for vid in ids:
        k = min(nlos_per_vehicle, len(sats))
        nlos[vid] = {sats[int(i)].sat for i in rng.choice(len(sats), size=k, replace=False)} if k else set()
    nlos_bias_of = {(vid, s): rng.uniform(*nlos_bias) for vid in ids for s in sorted(nlos[vid])}

    period = 20.0

    def state(vid: str, t: float) -> tuple[Vec, Vec, Vec]:
        """Antenna position, velocity (ECEF) and road-plane (n, d) at time t."""
        v = veh[vid]
        origin, tan, left, n = roads[int(v["road"])]
        w = 2 * math.pi / period
        s = v["s0"] + v["v0"] * t - v["amp"] / w * (math.cos(w * t + v["phase"]) - math.cos(v["phase"]))
        speed = v["v0"] + v["amp"] * math.sin(w * t + v["phase"])
        p = origin + s * tan + v["lane"] * left + v["h"] * n
        return p, speed * tan, n

    epochs: list[EpochInput] = []
    truth: list[dict[str, Vec]] = []
    for k in range(n_epochs):
        t = k * dt
        time = GpsTime(2300, start_tow + t)
        present = [vid for vid in ids if not (vid in absent and k in absent[vid])]
        vehicles: dict[str, VehicleEpochInput] = {}
        tr: dict[str, Vec] = {}
        for vid in present:
            v = veh[vid]
            p, vel, n = state(vid, t)
            tr[vid] = p
            d_plane = -float(n @ p)
            plane = PlaneObs(n.copy(), d_plane, plane_sigma) if with_planes else None
            if vid in outages and k in outages[vid]:
                vehicles[vid] = VehicleEpochInput(vid, time, plane=plane, antenna_height_m=float(v["h"]))
                continue
            b_gps = v["b0"] + v["drift"] * t + (C * 1e-3 if k >= clock_jumps.get(vid, n_epochs) else 0.0)
            prs: list[PseudorangeObs] = []
            for s in sats:
                sp = s.pos0 + s.vel * t
                clk = b_gps + (v["isb"] if s.sat[0] == "C" else 0.0)
                rho = float(np.linalg.norm(p - sp)) + clk - C * s.clock_s + rng.normal(0.0, pr_sigma)
                rho += nlos_bias_of.get((vid, s.sat), 0.0)
                prs.append(PseudorangeObs(s.sat, rho, sp, s.clock_s, pr_sigma))
            lim = sat_limit.get((vid, k))
            if lim is not None:
                prs = prs[:lim]
            spp = _spp(prs, ref)
            vel_obs = VelocityObs(vel + rng.normal(0.0, velocity_sigma, 3), 0.6) if lim is None else None
            drift = v["drift"] + rng.normal(0.0, 0.05) if lim is None else None
            vehicles[vid] = VehicleEpochInput(
                vid,
                time,
                tuple(prs),
                vel_obs,
                plane,
                spp_position=spp,
                clock_drift_mps=drift,
                antenna_height_m=float(v["h"]),
            )
        ranges: list[RangeObs] = []
        if len(present) > 1:
            pos = np.array([tr[v] for v in present])
            dist = np.linalg.norm(pos[:, None, :] - pos[None, :, :], axis=2)
            ii, jj = np.nonzero(np.triu(dist <= max_range, k=1))  # row-major: pairs (i < j) in order
            for i, j in zip(ii.tolist(), jj.tolist(), strict=True):
                d = float(dist[i, j])
                ranges.append(RangeObs(present[i], present[j], d + rng.normal(0.0, range_sigma), range_sigma))
        epochs.append(EpochInput(time, vehicles, tuple(ranges)))
        truth.append(tr)
    return SyntheticFleet(epochs, truth, ref, rot, ids, nlos)


@dataclass
class ErrorStats:
    h_rmse: float
    v_rmse: float
    h_max: float
    v_max: float
    n: int


def error_stats(
    fleet: SyntheticFleet,
    solutions: Sequence[FleetSolution],
    vehicles: Sequence[str] | None = None,
    skip: int = 0,
) -> ErrorStats:
    """Horizontal / vertical RMSE against truth over epochs >= skip (ENU at the reference point)."""
    hs: list[float] = []
    vs: list[float] = []
    for k, sol in enumerate(solutions):
        if k < skip:
            continue
        for vid, est in sol.estimates.items():
            if vehicles is not None and vid not in vehicles:
                continue
            e = fleet.enu_error(k, vid, est.position_m)
            hs.append(math.hypot(e[0], e[1]))
            vs.append(abs(e[2]))
    h = np.array(hs)
    v = np.array(vs)
    return ErrorStats(
        float(np.sqrt(np.mean(h**2))), float(np.sqrt(np.mean(v**2))), float(h.max()), float(v.max()), len(hs)
    )


def run(
    fleet: SyntheticFleet, cfg: FgoConfig, epochs: Sequence[EpochInput] | None = None
) -> list[FleetSolution]:
    """The estimator with `cfg` stepped over the fleet's epochs (or `epochs`), one solution each."""
    from coplane.fgo.engine import FusionEstimator

    est = FusionEstimator(cfg)
    return [est.step(e) for e in (fleet.epochs if epochs is None else epochs)]
