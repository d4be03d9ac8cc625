"""`FusionEstimator`: the fleet's sliding-window factor graph (paper Sec. IV), one epoch at a time.

Per epoch: validate the inputs (untrusted), add one position and one clock per GNSS system for each
vehicle that can be estimated, with its pseudorange (eq. 21), plane (eq. 24), velocity (eq. 36) and
clock factors, add the epoch's inter-vehicle ranges (eq. 27), split the window into clusters of
vehicles linked by ranges, solve each cluster with the configured solver and report the newest
epoch of every vehicle. The same inputs give bitwise the same estimates (only `solve_time_s`
varies): every loop runs in sorted order and GTSAM is deterministic for a fixed graph.

Never raises on bad data: invalid measurements are rejected and counted, vehicles that cannot be
estimated are listed in `FleetSolution.skipped` with the reason, and a GTSAM failure of a cluster is
retried with stronger priors, then that cluster's epoch is dropped.
"""

from __future__ import annotations

import math
import statistics
import time
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field

import gtsam
import numpy as np
from numpy.typing import NDArray

from coplane.estimation.contract import (
    EpochInput,
    FleetSolution,
    PlaneObs,
    PseudorangeObs,
    RangeObs,
    VehicleEpochInput,
    VehicleEstimate,
)
from coplane.estimation.limits import (
    MAX_DRIFT_MPS,
    MAX_PSEUDORANGE_M,
    MAX_RANGE_M,
    MAX_SIGMA_M,
    MAX_SPEED_MPS,
    RECEIVER_RADIUS_M,
    SAT_RADIUS_M,
)
from coplane.fgo import factors as F
from coplane.fgo.config import FgoConfig
from coplane.fgo.keys import CLOCK_CHR, KeyRegistry, clock_key, position_key
from coplane.fgo.window import (
    ClusterResult,
    ClusterView,
    Link,
    RangeEdge,
    SmootherCluster,
    StateBlock,
    StepRecord,
    Window,
    solve_lm_window,
)
from coplane.gnss.constants import C
from coplane.gtime import GpsTime

Vec = NDArray[np.float64]


FALLBACK_CLOCK_SIGMA_S = 1e-3  # strong-prior retry: clocks only need regularising


def _finite_vec3(v: object) -> Vec | None:
    try:
        a = np.asarray(v, dtype=float).reshape(3)
    except (TypeError, ValueError):
        return None
    return a if bool(np.all(np.isfinite(a))) else None


def _finite(x: object) -> float | None:
    try:
        f = float(x)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return None
    return f if math.isfinite(f) else None


@dataclass
class _Link:
    """The inter-epoch position factor of a new state: velocity (eq. 36) or motion fallback."""

    prev_key: int
    prev_step: int
    displacement: Vec
    sigma: float
    kind: str  # "velocity" | "motion"


@dataclass
class _ClockLink:
    """Receiver clock random walk to the vehicle's last clock of the same system."""

    prev_key: int
    prev_step: int
    step_m: float  # mean change (Doppler drift x dt), metres
    sigma_m: float


@dataclass
class _Pseudoranges:
    """One vehicle epoch's valid pseudoranges as arrays (satellites in the reception frame)."""

    sat_pos: NDArray[np.float64]  # (n, 3)
    rho: NDArray[np.float64]
    sat_clock: NDArray[np.float64]
    sigma: NDArray[np.float64]
    systems: list[str]  # per observation

    def __len__(self) -> int:
        return len(self.systems)


@dataclass
class _Prepared:
    """A vehicle epoch after validation, before its factors exist (needed for the rank check)."""

    vid: str
    prs: _Pseudoranges
    systems: list[str]
    plane: PlaneObs | None
    velocity: Vec | None
    drift: float | None
    init_pos: Vec
    link: _Link | None
    clock_init: dict[str, float]  # system -> seconds
    clock_links: dict[str, _ClockLink]
    rank_self: int  # independent position constraints of its own (pseudoranges, clock links, plane)


@dataclass
class _Slot:
    """A fixed-lag smoother that owns some vehicles' window states."""

    smoother: SmootherCluster
    vehicles: set[str]
    dirty: bool = False  # split: its remaining vehicles must be rebuilt before they are solved again


@dataclass
class _StepStats:
    iterations: int = 0
    error_before: float = 0.0
    error_after: float = 0.0
    anchors: int = 0
    rejected: dict[str, int] = field(default_factory=dict)
    skipped: dict[str, str] = field(default_factory=dict)

    def reject(self, kind: str, n: int = 1) -> None:
        self.rejected[kind] = self.rejected.get(kind, 0) + n


class ClusterFailure(RuntimeError):
    pass


class FusionEstimator:
    """Sliding-window cooperative positioning over GTSAM; `step()` once per epoch, in time order."""

    def __init__(self, config: FgoConfig | None = None) -> None:
        self.config = config or FgoConfig()
        self.reset()

    def reset(self) -> None:
        self._keys = KeyRegistry()
        self._window = Window(self.config.window_epochs)
        # Current estimate of every state in the window, kept as one gtsam.Values: a cluster's
        # initial values are one extract() and its result one update(), not a loop over keys.
        self._est = gtsam.Values()
        # Covariance of each state as reported when it was the newest: the source of the anchor.
        self._cov: dict[int, NDArray[np.float64]] = {}
        self._slots: list[_Slot] = []
        self._step = 0
        self._last_time: GpsTime | None = None

    # ------------------------------------------------------------------------------------------
    @property
    def tracked_vehicles(self) -> list[str]:
        """Vehicles with at least one state in the window."""
        return self._window.vehicles()

    def step(self, epoch: EpochInput) -> FleetSolution:
        t0 = time.perf_counter()
        cfg = self.config
        stats = _StepStats()
        if self._last_time is not None and not (epoch.time - self._last_time > 0.0):
            reason = f"epoch time {epoch.time} is not after the previous epoch {self._last_time}"
            stats.reject("epoch")
            return FleetSolution(
                epoch.time,
                {},
                time.perf_counter() - t0,
                {},
                skipped={vid: reason for vid in sorted(epoch.vehicles)},
                rejected=stats.rejected,
            )
        k = self._step
        t = epoch.time
        for blk in self._window.prune(k - cfg.window_epochs + 1):
            for key in blk.keys:
                self._est.erase(key)
            self._cov.pop(blk.pos_key, None)
        in_window = set(self._window.by_vehicle)
        for slot in self._slots:
            slot.vehicles &= in_window
        self._slots = [s for s in self._slots if s.vehicles]

        preps: dict[str, _Prepared] = {}
        for vid in sorted(epoch.vehicles):
            got = self._prepare(vid, epoch.vehicles[vid], t, stats)
            if isinstance(got, str):
                stats.skipped[vid] = got
            else:
                preps[vid] = got
        pairs = self._valid_ranges(epoch.ranges, preps, stats)
        for vid in self._undetermined(preps, pairs):
            stats.skipped[vid] = "not enough measurements to determine a first position"
            del preps[vid]
        pairs = [p for p in pairs if p[0] in preps and p[1] in preps]

        rec = StepRecord(k, t, {}, [])
        for vid in sorted(preps):
            blk = self._block(preps[vid], k, t)
            rec.blocks[vid] = blk
            self._est.insertPoint3(blk.pos_key, blk.init_pos)
            for ck, clock_s in blk.init_clocks.items():
                self._est.insert(ck, c=clock_s)  # keyword: pybind11 tries ~50 overloads for a float
        for a, b, rng, sigma in pairs:
            ka, kb = rec.blocks[a].pos_key, rec.blocks[b].pos_key
            rec.ranges.append(
                RangeEdge(a, b, ka, kb, F.range_factor(ka, kb, rng, sigma, cfg.robust, cfg.robust_tuning))
            )
        self._window.push(rec)

        n_clusters = 0
        for view in self._window.partition(cfg.split_clusters):
            new = [v for v in view.vehicles if v in rec.blocks]
            if not new:
                continue
            n_clusters += 1
            self._solve(view, rec, k, stats)

        estimates: dict[str, VehicleEstimate] = {}
        n_ranges: dict[str, int] = {}
        for r in rec.ranges:
            n_ranges[r.a] = n_ranges.get(r.a, 0) + 1
            n_ranges[r.b] = n_ranges.get(r.b, 0) + 1
        nan_cov = np.full((3, 3), np.nan)
        for vid in sorted(rec.blocks):
            blk = rec.blocks[vid]
            estimates[vid] = VehicleEstimate(
                vehicle_id=vid,
                time=t,
                position_m=np.array(self._est.atPoint3(blk.pos_key), dtype=float),
                covariance_m2=self._cov.get(blk.pos_key, nan_cov).copy(),
                clocks_s={s: float(self._est.atDouble(ck)) for s, ck in blk.clock_keys.items()},
                n_pseudoranges=blk.n_pseudoranges,
                n_ranges=n_ranges.get(vid, 0),
                plane_used=blk.plane_used,
                has_gnss_fix=blk.has_fix,
            )
        counts = {kind: n for kind, n in sorted(self._window.counts.items()) if n}
        if stats.anchors:
            counts["anchor"] = stats.anchors
        self._step += 1
        self._last_time = t
        return FleetSolution(
            time=t,
            estimates=estimates,
            solve_time_s=time.perf_counter() - t0,
            factor_counts=counts,
            iterations=stats.iterations,
            error_before=stats.error_before if n_clusters else float("nan"),
            error_after=stats.error_after if n_clusters else float("nan"),
            skipped=stats.skipped,
            rejected=stats.rejected,
            n_clusters=n_clusters,
        )

    # ------------------------------------------------------------------------------------------
    # validation and preparation

    def _valid_pseudoranges(self, prs: Sequence[PseudorangeObs], stats: _StepStats) -> _Pseudoranges:
        """Plausible, de-duplicated pseudoranges as arrays (vectorised: this runs per vehicle)."""
        n = len(prs)
        sats = np.full((n, 3), np.nan)
        num = np.full((n, 3), np.nan)  # rho, satellite clock, sigma
        try:
            sats[:] = [o.sat_pos_m for o in prs]
            num[:] = [(o.rho_m, o.sat_clock_s, o.sigma_m) for o in prs]
        except (TypeError, ValueError):  # a malformed one somewhere: convert one by one
            for i, o in enumerate(prs):
                v = _finite_vec3(o.sat_pos_m)
                if v is not None:
                    sats[i] = v
                num[i] = [
                    x if (x := _finite(y)) is not None else np.nan
                    for y in (o.rho_m, o.sat_clock_s, o.sigma_m)
                ]
        with np.errstate(invalid="ignore", over="ignore"):
            radius = np.sqrt(np.einsum("ij,ij->i", sats, sats))
            ok = (
                (radius > SAT_RADIUS_M[0])
                & (radius < SAT_RADIUS_M[1])
                & (np.abs(num[:, 0]) < MAX_PSEUDORANGE_M)
                & (np.abs(num[:, 1]) < 1.0)
                & (num[:, 2] > 0.0)
                & (num[:, 2] < MAX_SIGMA_M)
            )
        keep: list[int] = []
        seen: set[str] = set()
        for i, (good, o) in enumerate(zip(ok.tolist(), prs, strict=True)):
            sat = o.sat
            if good and isinstance(sat, str) and len(sat) >= 2 and sat[0] in CLOCK_CHR and sat not in seen:
                seen.add(sat)
                keep.append(i)
        if len(keep) < n:
            stats.reject("pseudorange", n - len(keep))
            sats, num = sats[keep], num[keep]
        return _Pseudoranges(sats, num[:, 0], num[:, 1], num[:, 2], [prs[i].sat[0] for i in keep])

    @staticmethod
    def _gate(
        prs: _Pseudoranges, predicted: Vec, k: float, sigma_pred: float, stats: _StepStats
    ) -> _Pseudoranges:
        """Drop pseudoranges whose innovation at the predicted position exceeds k sigma."""
        resid = prs.rho + C * prs.sat_clock - np.linalg.norm(prs.sat_pos - predicted, axis=1)
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
        return _Pseudoranges(
            prs.sat_pos[keep],
            prs.rho[keep],
            prs.sat_clock[keep],
            prs.sigma[keep],
            [s for s, kk in zip(prs.systems, keep, strict=True) if kk],
        )

    def _valid_plane(self, plane: PlaneObs | None, stats: _StepStats) -> PlaneObs | None:
        if plane is None:
            return None
        n = _finite_vec3(plane.normal)
        d = _finite(plane.d_m)
        sg = _finite(plane.sigma_m)
        if (
            n is None
            or d is None
            or sg is None
            or not (0.0 < sg < MAX_SIGMA_M)
            or abs(np.linalg.norm(n) - 1.0) > 1e-3
        ):
            stats.reject("plane")
            return None
        return plane

    def _prepare(self, vid: str, vin: VehicleEpochInput, t: GpsTime, stats: _StepStats) -> _Prepared | str:
        cfg = self.config
        if not isinstance(vin, VehicleEpochInput) or vin.vehicle_id != vid:
            stats.reject("vehicle")
            return "vehicle input does not match its id"
        if abs(vin.time - t) > 0.5:
            stats.reject("vehicle")
            return f"vehicle epoch time {vin.time} is not the epoch's time {t}"
        prs = self._valid_pseudoranges(vin.pseudoranges, stats)
        plane = self._valid_plane(vin.plane, stats) if cfg.use_planes else None
        velocity = None
        if vin.velocity is not None:
            velocity = _finite_vec3(vin.velocity.velocity_mps)
            if velocity is None or float(np.linalg.norm(velocity)) > MAX_SPEED_MPS:
                stats.reject("velocity")
                velocity = None
        spp = _finite_vec3(vin.spp_position) if vin.spp_position is not None else None
        if spp is not None and not RECEIVER_RADIUS_M[0] < float(np.linalg.norm(spp)) < RECEIVER_RADIUS_M[1]:
            stats.reject("spp")
            spp = None
        drift = _finite(vin.clock_drift_mps) if vin.clock_drift_mps is not None else None
        if drift is not None and abs(drift) > MAX_DRIFT_MPS:
            stats.reject("clock_drift")
            drift = None

        hist = self._window.by_vehicle.get(vid)
        link: _Link | None = None
        if hist:
            last = hist[-1]
            dt = t - last.time
            p_last = self._position(last.pos_key)
            if cfg.use_velocity:
                link = self._displacement(hist, velocity, dt)
                init = p_last + link.displacement
            elif spp is not None:
                init = spp
            else:
                init = p_last + (velocity * dt if velocity is not None else 0.0)
        elif spp is not None:
            init = spp
        else:
            return "no SPP position to initialise from" if prs else "no GNSS and no state in the window"

        if hist and cfg.gate_k is not None and len(prs):
            prs = self._gate(prs, init, cfg.gate_k, cfg.gate_prediction_sigma_m, stats)
        systems = sorted(set(prs.systems))
        # initial clock per system: median residual at the initial position (robust to NLOS)
        clock_init: dict[str, float] = {}
        if len(prs):
            resid = prs.rho + C * prs.sat_clock - np.linalg.norm(prs.sat_pos - init, axis=1)
            by_system: dict[str, list[float]] = {s: [] for s in systems}
            for s, r in zip(prs.systems, resid.tolist(), strict=True):
                by_system[s].append(r)
            # statistics.median: np.median's value, without its overhead on a dozen numbers
            clock_init = {s: statistics.median(by_system[s]) / C for s in systems}
        clock_links: dict[str, _ClockLink] = {}
        for s in systems:
            prev = next((b for b in reversed(hist) if s in b.clock_keys), None) if hist else None
            if prev is None:
                continue
            dt = t - prev.time
            drifts = [d for d in (drift, prev.clock_drift_mps) if d is not None]
            mean = sum(drifts) / len(drifts) if drift is not None else 0.0  # mean of both when known
            sigma = F.clock_step_sigma_m(dt, drift is not None, cfg.clock_rw_sigma, cfg.clock_drift_sigma)
            ck = prev.clock_keys[s]
            predicted_m = C * float(self._est.atDouble(ck)) + mean * dt
            if abs(C * clock_init[s] - predicted_m) > max(cfg.clock_jump_m, 5.0 * sigma):
                stats.reject("clock_link")  # a receiver clock jump (e.g. 1 ms steering): restart
                continue
            clock_links[s] = _ClockLink(ck, prev.step, mean * dt, sigma)
        rank = sum(max(0, prs.systems.count(s) - 1 + (1 if s in clock_links else 0)) for s in systems) + (
            1 if plane is not None else 0
        )
        return _Prepared(vid, prs, systems, plane, velocity, drift, init, link, clock_init, clock_links, rank)

    def _displacement(self, hist: deque[StateBlock], velocity: Vec | None, dt: float) -> _Link:
        """Eq. 35-36 displacement to the previous state, or the motion fallback without Doppler.

        Both Doppler velocities known: their mean (exact for constant acceleration); only the new
        one: v_t * dt (the paper). No Doppler now: the last known velocity (Doppler of the previous
        state, else the difference of the last two estimates) with sigma motion_sigma * dt, else
        zero with sigma max_speed * dt.
        """
        cfg = self.config
        last = hist[-1]
        if velocity is not None:
            v = 0.5 * (velocity + last.velocity) if last.velocity is not None else velocity
            return _Link(last.pos_key, last.step, v * dt, cfg.sigma_v * dt, "velocity")
        v_last: Vec | None = last.velocity
        if v_last is None and len(hist) >= 2:
            prev = hist[-2]
            v_last = (self._position(last.pos_key) - self._position(prev.pos_key)) / (last.time - prev.time)
        if v_last is not None:
            return _Link(last.pos_key, last.step, v_last * dt, cfg.motion_sigma * dt, "motion")
        return _Link(last.pos_key, last.step, np.zeros(3), cfg.max_speed * dt, "motion")

    def _valid_ranges(
        self, ranges: Sequence[RangeObs], preps: dict[str, _Prepared], stats: _StepStats
    ) -> list[tuple[str, str, float, float]]:
        if not self.config.use_ranging:
            return []
        out: dict[tuple[str, str], tuple[float, float]] = {}
        seen: set[tuple[str, str]] = set()
        for r in ranges:
            rng = _finite(r.range_m)
            if not isinstance(r.a, str) or not isinstance(r.b, str) or r.a == r.b or rng is None:
                stats.reject("range")
                continue
            if not 0.0 < rng < MAX_RANGE_M:
                stats.reject("range")
                continue
            pair = (r.a, r.b) if r.a < r.b else (r.b, r.a)
            if pair in seen:
                stats.reject("range")  # a pair at most once per epoch
                continue
            seen.add(pair)
            if pair[0] not in preps or pair[1] not in preps:
                continue  # a vehicle without an estimate this epoch: not an error
            sg = _finite(r.sigma_m)
            out[pair] = (rng, sg if sg is not None and 0.0 < sg < MAX_SIGMA_M else self.config.range_sigma)
        return [(a, b, rng, sg) for (a, b), (rng, sg) in sorted(out.items())]

    @staticmethod
    def _undetermined(preps: dict[str, _Prepared], pairs: list[tuple[str, str, float, float]]) -> list[str]:
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
                    1 for a, b, _, _ in pairs if (a == v and b in det) or (b == v and a in det)
                )
                if n >= 3:
                    det.add(v)
                    changed = True
        return [v for v in sorted(preps) if v not in det]

    # ------------------------------------------------------------------------------------------
    # factors of one vehicle epoch

    def _block(self, p: _Prepared, k: int, t: GpsTime) -> StateBlock:
        cfg = self.config
        slot = self._keys.slot(p.vid)
        pk = position_key(slot, k)
        cks = {s: clock_key(slot, k, s) for s in p.systems}
        g = gtsam.NonlinearFactorGraph()
        counts: dict[str, int] = {}
        init_clocks = {cks[s]: b for s, b in p.clock_init.items()}
        prs = p.prs
        if len(prs):
            for f in F.pseudorange_factors(
                pk,
                [cks[sys] for sys in prs.systems],
                prs.rho,
                prs.sat_pos,
                prs.sat_clock,
                prs.sigma,
                p.init_pos,
                cfg.robust,
                cfg.robust_tuning,
            ):
                g.add(f)
            counts["pseudorange"] = len(prs)
        if p.plane is not None:
            g.add(F.plane_factor(pk, p.plane))
            counts["plane"] = 1
        links: list[Link] = []
        if p.link is not None:
            disp = F.displacement_factor(p.link.prev_key, pk, p.link.displacement, p.link.sigma)
            links.append(Link(p.link.prev_step, p.link.kind, disp))
        for s, cl in sorted(p.clock_links.items()):
            links.append(
                Link(cl.prev_step, "clock", F.clock_factor(cl.prev_key, cks[s], cl.step_m, cl.sigma_m))
            )
        return StateBlock(
            vehicle_id=p.vid,
            step=k,
            time=t,
            pos_key=pk,
            clock_keys=cks,
            init_pos=np.asarray(p.init_pos, dtype=float),
            init_clocks=init_clocks,
            graph=g,
            counts=counts,
            links=links,
            n_pseudoranges=len(p.prs),
            plane_used=p.plane is not None,
            velocity=p.velocity,
            clock_drift_mps=p.drift,
            has_fix=len(p.prs) >= cfg.min_fix_pseudoranges,
        )

    # ------------------------------------------------------------------------------------------
    # solving a cluster

    def _position(self, key: int) -> Vec:
        return np.array(self._est.atPoint3(key), dtype=float)

    def _initial(self, blocks: Sequence[StateBlock]) -> gtsam.Values:
        return self._est.extract([key for b in blocks for key in b.keys])

    def _anchors(self, vehicles: Sequence[str]) -> list[gtsam.NonlinearFactor]:
        """Loose priors on each vehicle's oldest window state that was solved before.

        Mean: its latest estimate. Covariance: what was reported for it when it was the newest
        state (a filtered, hence conservative, marginal) with eigenvalues floored at
        anchor_sigma^2: negligible next to GNSS in the window, and during an outage longer than the
        window it grows like dead reckoning instead of pinning the vehicle.
        """
        out: list[gtsam.NonlinearFactor] = []
        for v in vehicles:
            oldest = self._window.by_vehicle[v][0]
            if oldest.step == self._step:
                continue  # created this epoch: nothing to anchor to
            cov = F.floored_covariance(self._cov.get(oldest.pos_key), self.config.anchor_sigma)
            out.append(F.position_prior(oldest.pos_key, self._position(oldest.pos_key), cov))
        return out

    def _strong_priors(self, blocks: Sequence[StateBlock]) -> list[gtsam.NonlinearFactor]:
        """Retry after a GTSAM failure: every state gets a prior at its current value."""
        cov = np.eye(3) * self.config.anchor_sigma**2
        out: list[gtsam.NonlinearFactor] = []
        for b in blocks:
            out.append(F.position_prior(b.pos_key, self._position(b.pos_key), cov))
            for ck in b.clock_keys.values():
                out.append(F.clock_prior(ck, float(self._est.atDouble(ck)), FALLBACK_CLOCK_SIGMA_S))
        return out

    def _solve(self, view: ClusterView, rec: StepRecord, k: int, stats: _StepStats) -> None:
        new = [v for v in view.vehicles if v in rec.blocks]
        try:
            if self.config.solver == "lm-window":
                res = self._solve_lm(view, rec, k, stats)
            else:
                res = self._solve_smoother(view, rec, k, stats)
        except ClusterFailure as exc:
            self._drop_new(new, rec, f"solver failed, epoch dropped: {exc}", stats)
            self._slots = [s for s in self._slots if not (s.vehicles & set(view.vehicles))]
            return
        self._est.update(res.values)
        for key, cov in res.covariances.items():
            self._cov[key] = 0.5 * (cov + cov.T)
        stats.iterations = max(stats.iterations, res.iterations)
        stats.error_before += res.error_before
        stats.error_after += res.error_after

    def _drop_new(self, vehicles: Sequence[str], rec: StepRecord, reason: str, stats: _StepStats) -> None:
        for v in vehicles:
            blk = rec.blocks.get(v)
            if blk is None:
                continue
            for key in blk.keys:
                self._est.erase(key)
            stats.skipped[v] = reason
        self._window.drop_new(vehicles)

    def _cov_keys(self, view: ClusterView, rec: StepRecord) -> list[int]:
        if not self.config.compute_covariance:
            return []
        return [rec.blocks[v].pos_key for v in view.vehicles if v in rec.blocks]

    def _solve_lm(self, view: ClusterView, rec: StepRecord, k: int, stats: _StepStats) -> ClusterResult:
        cfg = self.config
        oldest = k - cfg.window_epochs + 1
        anchors = self._anchors(view.vehicles)
        initial = self._initial(view.blocks)
        cov_keys = self._cov_keys(view, rec)
        try:
            res = solve_lm_window(cfg, view.blocks, view.ranges, anchors, initial, cov_keys, oldest)
        except Exception:  # GTSAM raises RuntimeError subclasses (IndeterminantLinearSystem...)
            try:
                priors = anchors + self._strong_priors(view.blocks)
                res = solve_lm_window(cfg, view.blocks, view.ranges, priors, initial, cov_keys, oldest)
            except Exception as exc:
                raise ClusterFailure(_short(exc)) from exc
        stats.anchors += len(anchors)
        return res

    def _solve_smoother(self, view: ClusterView, rec: StepRecord, k: int, stats: _StepStats) -> ClusterResult:
        """Feed the cluster's smoother the new epoch, or (re)build one from the window.

        A smoother can take the new epoch when it already owns exactly this cluster's vehicles
        (plus vehicles seen for the first time). A merge of clusters, a split, a vehicle whose
        earlier states belong to no smoother, or a failed update rebuild it from the window with
        the same anchor priors as lm-window, since what was marginalised cannot be moved between
        smoothers.
        """
        cfg = self.config
        members = set(view.vehicles)
        slots = [s for s in self._slots if s.vehicles & members]
        cov_keys = self._cov_keys(view, rec)
        oldest = k - cfg.window_epochs + 1
        keys = [key for b in view.blocks for key in b.keys]
        if len(slots) == 1 and not slots[0].dirty and slots[0].vehicles <= members:
            slot = slots[0]
            if all(v in slot.vehicles or self._window.by_vehicle[v][0].step == k for v in view.vehicles):
                blocks = [rec.blocks[v] for v in view.vehicles if v in rec.blocks]
                ranges = [r for r in rec.ranges if r.a in members]
                stamps = {key: float(k) for b in blocks for key in b.keys}
                fresh = any(len(self._window.by_vehicle[b.vehicle_id]) == 1 for b in blocks)  # from SPP
                try:
                    res = slot.smoother.update(
                        blocks,
                        ranges,
                        [],
                        self._initial(blocks),
                        stamps,
                        cov_keys,
                        oldest,
                        keys,
                        converge=fresh,
                    )
                    slot.vehicles |= members
                    return res
                except Exception:
                    pass  # rebuild below; the smoother's state is unknown after a failed update
        for s in slots:
            s.vehicles -= members
            s.dirty = True  # what remains of it was split off: rebuild before solving it again
        self._slots = [s for s in self._slots if s.vehicles]
        anchors = self._anchors(view.vehicles)
        stamps = {key: float(b.step) for b in view.blocks for key in b.keys}
        initial = self._initial(view.blocks)
        last_exc: Exception | None = None
        for priors in (anchors, anchors + self._strong_priors(view.blocks)):
            sm = SmootherCluster(cfg, members)
            try:
                res = sm.update(
                    view.blocks, view.ranges, priors, initial, stamps, cov_keys, oldest, keys, converge=True
                )
            except Exception as exc:
                last_exc = exc
                continue
            self._slots.append(_Slot(sm, set(members)))
            stats.anchors += len(anchors)
            return res
        assert last_exc is not None
        raise ClusterFailure(_short(last_exc)) from last_exc


def _short(exc: BaseException) -> str:
    text = f"{type(exc).__name__}: {exc}".strip()
    first = text.splitlines()[0] if text else type(exc).__name__
    return first[:200]
