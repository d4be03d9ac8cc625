"""`FleetFilter`: the EKF machinery shared by the Non-CP, DD-CP and GAMP baselines.

A joint state over any set of vehicles, with add/remove of vehicles and clocks, prediction, a
chi-square gated batch update (Joseph form) and the per-vehicle start / restart / clock-jump rules.
The Non-CP EKF runs one filter per vehicle, DD-CP one over the whole fleet, GAMP uses the
per-vehicle filters for its priors. Equations, noise values and the gate: docs/methods.md.

State of a vehicle (ECEF, metres): position p (3), velocity v (3), receiver clock drift d (m/s,
one per receiver: the oscillator is shared) and one clock b_s per GNSS system (m; the per-system
clock absorbs the inter-system bias). Constant-velocity model with white-noise acceleration (a
larger spectral density horizontally than vertically, rotated from ENU to ECEF), clock phase and
frequency random walks. Measurements: corrected pseudoranges (rho = |p - s| + b_s - c dt_s), the
Doppler least-squares velocity of the node (`VelocityObs`; the per-satellite Doppler is not in the
estimator interface, so the filter uses the node's velocity solution as a 3-D measurement) and
the Doppler clock drift. Every measurement passes a chi-square innovation gate first.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from coplane.baselines.measurements import VehicleMeasurements, clock_residuals
from coplane.baselines.rows import GateResult, Rows
from coplane.errors import require_finite_positive
from coplane.geo import ecef_to_geodetic, enu_rotation
from coplane.gnss.constants import C
from coplane.gnss.lsq import chi2_threshold
from coplane.gtime import GpsTime
from coplane.typing import Mat, Vec


@dataclass(frozen=True)
class EkfConfig:
    """Process noise, initialisation, gate and recovery rules of the EKF baselines (docs/methods.md)."""

    # white-noise acceleration spectral densities (m^2/s^3) in the local ENU frame
    accel_psd_h: float = 1.0
    accel_psd_v: float = 0.1
    # receiver clock: phase (m^2/s) and frequency (m^2/s^3) random walks; per-system part (ISB)
    clock_psd: float = 1.0
    drift_psd: float = 0.1
    isb_psd: float = 1e-4
    # chi-square innovation gate: false-alarm probability (1e-3: 10.83 for one dof, 16.27 for 3)
    gate_probability: float = 1e-3
    # a system's median pseudorange innovation beyond max(clock_jump_m, 5 sigma) is a receiver
    # clock jump (1 ms steering is 3e5 m): the clock is re-initialised, not the position
    clock_jump_m: float = 1000.0
    init_position_sigma_m: float = 10.0
    init_velocity_sigma_mps: float = 20.0
    init_clock_sigma_m: float = 10.0
    init_drift_sigma_mps: float = 300.0
    # a vehicle not updated by GNSS for longer than this, or with a 1-sigma position beyond
    # max_position_sigma_m, restarts from its SPP when it has one; states of vehicles absent from
    # the epoch inputs for longer than max_gap_s are dropped
    max_gap_s: float = 30.0
    max_position_sigma_m: float = 100.0
    # more than this share of at least `divergence_min` pseudoranges failing the gate means the
    # prediction, not the measurements, is wrong: restart the vehicle from its SPP
    divergence_fraction: float = 0.5
    divergence_min: int = 6
    min_fix_pseudoranges: int = 4
    use_velocity: bool = True
    use_drift: bool = True

    def __post_init__(self) -> None:
        require_finite_positive(
            self,
            (
                "accel_psd_h",
                "accel_psd_v",
                "clock_psd",
                "drift_psd",
                "isb_psd",
                "clock_jump_m",
                "init_position_sigma_m",
                "init_velocity_sigma_mps",
                "init_clock_sigma_m",
                "init_drift_sigma_mps",
                "max_gap_s",
                "max_position_sigma_m",
            ),
        )
        if not 0.0 < self.gate_probability < 1.0:
            raise ValueError(f"gate_probability must be in (0, 1), got {self.gate_probability!r}")

    def gate(self, dof: int) -> float:
        return chi2_threshold(self.gate_probability, dof)


P_NAMES = ("px", "py", "pz")
V_NAMES = ("vx", "vy", "vz")


class FleetFilter:
    """A joint EKF state over a dynamic set of vehicles (names -> indices kept in one dict).

    Each vehicle has px py pz vx vy vz d and one b:<system> per GNSS system it has used. Adding a
    vehicle or a clock appends states (zero cross-covariance); removing deletes them.
    """

    def __init__(self, config: EkfConfig) -> None:
        self.config = config
        self.names: list[tuple[str, str]] = []
        self.index: dict[tuple[str, str], int] = {}
        self.x = np.zeros(0)
        self.P = np.zeros((0, 0))
        self.time: GpsTime | None = None
        self.last_gnss: dict[str, GpsTime] = {}  # last GNSS update per vehicle
        self.last_seen: dict[tuple[str, str], GpsTime] = {}  # last use of a clock / vehicle
        self.started: dict[str, GpsTime] = {}  # when each vehicle was last (re)started

    # -- layout ------------------------------------------------------------------------------
    def _reindex(self) -> None:
        self.index = {n: i for i, n in enumerate(self.names)}

    def vehicles(self) -> list[str]:
        return sorted({v for v, _ in self.names})

    def has(self, vid: str) -> bool:
        return (vid, "px") in self.index

    def idx(self, vid: str, names: Sequence[str]) -> list[int]:
        return [self.index[(vid, n)] for n in names]

    def pos_idx(self, vid: str) -> list[int]:
        return self.idx(vid, P_NAMES)

    def clock_systems(self, vid: str) -> list[str]:
        return sorted(n[2:] for v, n in self.names if v == vid and n.startswith("b:"))

    def _append(
        self, vid: str, names: Sequence[str], values: Sequence[float], variances: Sequence[float]
    ) -> None:
        n0 = len(self.names)
        k = len(names)
        self.names.extend((vid, n) for n in names)
        self.x = np.concatenate([self.x, np.asarray(values, dtype=float)])
        p = np.zeros((n0 + k, n0 + k))
        p[:n0, :n0] = self.P
        p[n0:, n0:] = np.diag(np.asarray(variances, dtype=float))
        self.P = p
        self._reindex()

    def _delete(self, keep: list[int]) -> None:
        self.names = [self.names[i] for i in keep]
        self.x = self.x[keep]
        self.P = self.P[np.ix_(keep, keep)]
        self._reindex()

    def remove_vehicle(self, vid: str) -> None:
        self._delete([i for i, (v, _) in enumerate(self.names) if v != vid])
        self.last_gnss.pop(vid, None)
        self.started.pop(vid, None)
        for key in [k for k in self.last_seen if k[0] == vid]:
            del self.last_seen[key]

    def remove_clock(self, vid: str, system: str) -> None:
        self._delete([i for i, n in enumerate(self.names) if n != (vid, f"b:{system}")])
        self.last_seen.pop((vid, f"b:{system}"), None)

    def init_vehicle(self, m: VehicleMeasurements, t: GpsTime) -> bool:
        """(Re)start a vehicle at its SPP (clocks: median residuals there); False without SPP.

        The SPP comes from the same pseudoranges the update then applies; its loose prior
        (init_position_sigma_m) keeps that double use negligible.
        """
        cfg = self.config
        if m.spp is None:
            return False
        if self.has(m.vehicle_id):
            self.remove_vehicle(m.vehicle_id)
        # means from this epoch's measurements, loose variances: the update that follows applies
        # those measurements once (a tight prior from them would count them twice)
        vel = m.velocity if m.velocity is not None and cfg.use_velocity else np.zeros(3)
        drift = m.drift if m.drift is not None and cfg.use_drift else 0.0
        vvar, dvar = cfg.init_velocity_sigma_mps**2, cfg.init_drift_sigma_mps**2
        self._append(
            m.vehicle_id,
            (*P_NAMES, *V_NAMES, "d"),
            (*m.spp, *vel, drift),
            (*(cfg.init_position_sigma_m**2,) * 3, *(vvar,) * 3, dvar),
        )
        for s, b in clock_residuals(m, m.spp).items():
            self.add_clock(m.vehicle_id, s, b, t)
        self.last_gnss[m.vehicle_id] = t
        self.last_seen[(m.vehicle_id, "px")] = t
        self.started[m.vehicle_id] = t
        return True

    def add_clock(self, vid: str, system: str, value_m: float, t: GpsTime) -> None:
        self._append(vid, (f"b:{system}",), (value_m,), (self.config.init_clock_sigma_m**2,))
        self.last_seen[(vid, f"b:{system}")] = t

    def reset_clock(self, vid: str, system: str, value_m: float) -> None:
        """Forget a clock's past (a receiver clock jump): new value, initial variance, no correlation."""
        i = self.index[(vid, f"b:{system}")]
        self.x[i] = value_m
        self.P[i, :] = 0.0
        self.P[:, i] = 0.0
        self.P[i, i] = self.config.init_clock_sigma_m**2

    def position(self, vid: str) -> Vec:
        return self.x[self.pos_idx(vid)].copy()

    def position_cov(self, vid: str) -> Mat:
        i = self.pos_idx(vid)
        return self.P[np.ix_(i, i)].copy()

    def clocks_s(self, vid: str) -> dict[str, float]:
        return {s: float(self.x[self.index[(vid, f"b:{s}")]]) / C for s in self.clock_systems(vid)}

    # -- prediction --------------------------------------------------------------------------
    def predict(self, t: GpsTime) -> None:
        """Constant velocity and clock drift over dt; process noise Q (docs/methods.md)."""
        if self.time is None:
            self.time = t
            return
        dt = t - self.time
        self.time = t
        if dt <= 0 or not len(self.x):
            return
        cfg = self.config
        n = len(self.x)
        f = np.eye(n)
        q = np.zeros((n, n))
        for vid in self.vehicles():
            ip, iv = self.pos_idx(vid), self.idx(vid, V_NAMES)
            idr = self.index[(vid, "d")]
            f[ip, iv] = dt
            lat, lon, _ = ecef_to_geodetic(self.x[ip])
            rot = enu_rotation(lat, lon)  # rows E, N, U
            s = rot.T @ np.diag([cfg.accel_psd_h, cfg.accel_psd_h, cfg.accel_psd_v]) @ rot
            q[np.ix_(ip, ip)] = s * dt**3 / 3.0
            q[np.ix_(ip, iv)] = s * dt**2 / 2.0
            q[np.ix_(iv, ip)] = s * dt**2 / 2.0
            q[np.ix_(iv, iv)] = s * dt
            q[idr, idr] = cfg.drift_psd * dt
            ib = [self.index[(vid, f"b:{sy}")] for sy in self.clock_systems(vid)]
            for a in ib:
                f[a, idr] = dt
                q[a, idr] = q[idr, a] = cfg.drift_psd * dt**2 / 2.0
                for b in ib:  # one oscillator: the clocks of all systems move together ...
                    q[a, b] = cfg.clock_psd * dt + cfg.drift_psd * dt**3 / 3.0
                q[a, a] += cfg.isb_psd * dt  # ... up to a slowly wandering inter-system bias
        self.x = f @ self.x
        self.P = f @ self.P @ f.T + q
        self.P = 0.5 * (self.P + self.P.T)

    # -- measurements ------------------------------------------------------------------------
    def pseudorange_rows(self, rows: Rows, m: VehicleMeasurements) -> None:
        """One gating group per pseudorange: rho_c - (|p - s| + b_sys)."""
        if not len(m):
            return
        vid = m.vehicle_id
        p = self.position(vid)
        d = p - m.sat_pos
        r = np.linalg.norm(d, axis=1)
        u = d / r[:, None]
        ip = self.pos_idx(vid)
        for k in range(len(m)):
            ib = self.index[(vid, f"b:{m.systems[k]}")]
            h = np.zeros(rows.n_state)
            h[ip] = u[k]
            h[ib] = 1.0
            nu = m.rho_c[k] - r[k] - self.x[ib]
            rows.add([nu], [h], np.array([[m.sigma[k] ** 2]]), "pseudorange", (vid,))

    def velocity_rows(self, rows: Rows, m: VehicleMeasurements) -> None:
        vid = m.vehicle_id
        if m.velocity is not None and self.config.use_velocity:
            iv = self.idx(vid, V_NAMES)
            hs = []
            for k in range(3):
                h = np.zeros(rows.n_state)
                h[iv[k]] = 1.0
                hs.append(h)
            rows.add(list(m.velocity - self.x[iv]), hs, np.eye(3) * m.velocity_sigma**2, "velocity", (vid,))
        if m.drift is not None and self.config.use_drift:
            i = self.index[(vid, "d")]
            h = np.zeros(rows.n_state)
            h[i] = 1.0
            rows.add([m.drift - self.x[i]], [h], np.array([[m.velocity_sigma**2]]), "clock_drift", (vid,))

    def innovation_cov(self, rows: Rows) -> tuple[Mat, Vec, Mat]:
        h = np.array(rows.h).reshape(len(rows), rows.n_state)
        nu = np.array(rows.nu)
        r = scipy.linalg.block_diag(*rows.r_blocks) if rows.r_blocks else np.zeros((0, 0))
        return h, nu, r

    def gate(self, rows: Rows, groups: Iterable[int] | None = None) -> GateResult:
        """Chi-square test of each group's innovation against its predicted covariance H P H' + R."""
        h, nu, r = self.innovation_cov(rows)
        acc: list[int] = []
        rej: list[int] = []
        for g in range(len(rows.groups)) if groups is None else groups:
            idx = rows.groups[g][0]
            hg = h[idx]
            s = hg @ self.P @ hg.T + r[np.ix_(idx, idx)]
            try:
                nis = float(nu[idx] @ np.linalg.solve(s, nu[idx]))
            except np.linalg.LinAlgError:
                nis = math.inf
            (acc if nis <= self.config.gate(len(idx)) else rej).append(g)
        return GateResult(acc, rej)

    def update(self, rows: Rows, groups: Sequence[int]) -> bool:
        """Batch EKF update (Joseph form) with the chosen groups; False (state unchanged) on failure."""
        idx = [i for g in groups for i in rows.groups[g][0]]
        if not idx:
            return True
        h, nu, r = self.innovation_cov(rows)
        h, nu, r = h[idx], nu[idx], r[np.ix_(idx, idx)]
        ph = self.P @ h.T
        s = h @ ph + r
        s = 0.5 * (s + s.T)
        try:
            cf = scipy.linalg.cho_factor(s)
            k = scipy.linalg.cho_solve(cf, ph.T).T
        except (np.linalg.LinAlgError, ValueError):
            return False
        x = self.x + k @ nu
        ikh = np.eye(len(self.x)) - k @ h
        p = ikh @ self.P @ ikh.T + k @ r @ k.T
        p = 0.5 * (p + p.T)
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(p))):
            return False
        self.x, self.P = x, p
        return True

    # -- per-vehicle epoch housekeeping ---------------------------------------------------------
    def prepare_vehicle(self, m: VehicleMeasurements, t: GpsTime, rejected: Counter[str]) -> str | None:
        """Make vehicle `m` ready for its measurement update: start, restart or fix its clocks.

        Returns a skip reason when the vehicle has no state and cannot get one.
        """
        cfg = self.config
        vid = m.vehicle_id
        if self.has(vid):
            last = self.last_gnss.get(vid)
            stale = last is None or t - last > cfg.max_gap_s
            lost = float(np.sqrt(np.max(np.diag(self.position_cov(vid))))) > cfg.max_position_sigma_m
            if (stale or lost) and m.spp is not None and len(m):
                self.init_vehicle(m, t)
                rejected["reinit"] += 1
                return None
        elif not self.init_vehicle(m, t):
            return "no SPP position to initialise from" if len(m) else "no GNSS and no state yet"
        self.last_seen[(vid, "px")] = t
        if not len(m):
            return None
        p = self.position(vid)
        for s, res in clock_residuals(m, p).items():
            key = (vid, f"b:{s}")
            if key not in self.index:
                self.add_clock(vid, s, res, t)
                continue
            i = self.index[key]
            jump = res - self.x[i]
            sigma = math.sqrt(max(self.P[i, i], 0.0))
            if abs(jump) > max(cfg.clock_jump_m, 5.0 * sigma):
                self.reset_clock(vid, s, res)
                rejected["clock_reset"] += 1
            self.last_seen[key] = t
        return None

    def drop_stale(self, t: GpsTime) -> None:
        """Forget vehicles absent, and clocks unused, for longer than max_gap_s."""
        gap = self.config.max_gap_s
        for vid in self.vehicles():
            seen = self.last_seen.get((vid, "px"))
            if seen is None or t - seen > gap:
                self.remove_vehicle(vid)
                continue
            for s in self.clock_systems(vid):
                used = self.last_seen.get((vid, f"b:{s}"))
                if used is None or t - used > gap:
                    self.remove_clock(vid, s)
