"""`FusionEstimator`: the fleet's sliding-window factor graph (paper Sec. IV), one epoch at a time.

Per epoch: validate the inputs (untrusted; `coplane.estimation.validate_epoch`), prepare each
vehicle (`prepare`), add one position and one clock per GNSS system for each
vehicle that can be estimated, with its pseudorange (eq. 21), plane (eq. 24), velocity (eq. 36) and
clock factors (`blocks`), add the epoch's inter-vehicle ranges (eq. 27), split the window into clusters of
vehicles linked by ranges, solve each cluster with the configured solver (`solve`) and report the newest
epoch of every vehicle. The same inputs give bitwise the same estimates (only `solve_time_s`
varies): every loop runs in sorted order and GTSAM is deterministic for a fixed graph.

Never raises on bad data: invalid measurements are rejected and counted, vehicles that cannot be
estimated are listed in `FleetSolution.skipped` with the reason, and a GTSAM failure of a cluster is
retried with stronger priors, then that cluster's epoch is dropped.

Resuming after a restart (`seed`): a vehicle's last solved state from the fusion server's log
becomes, for its next new track, the initial value and a prior (position predicted by its Doppler
velocity, covariance grown with the elapsed time and floored like the window's anchors; clocks
with their random-walk sigma), so the track continues instead of restarting from SPP alone.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from coplane.estimation.contract import EpochInput, FleetSolution, VehicleEstimate, VehicleSeed
from coplane.estimation.validate import ValidRange, out_of_order_reason, skipped_epoch, validate_epoch
from coplane.fgo import factors as F
from coplane.fgo.blocks import build_block
from coplane.fgo.config import FgoConfig
from coplane.fgo.prepare import Prepared, prepare_vehicle, undetermined
from coplane.fgo.solve import ClusterSolver
from coplane.fgo.state import GraphState, StepStats
from coplane.fgo.window import RangeEdge, StateBlock, StepRecord, Window
from coplane.gnss.constants import C
from coplane.gtime import GpsTime

SEED_MAX_AGE_S = 60.0  # a seed older than this (GPS time) says little about where the vehicle is


class FusionEstimator:
    """Sliding-window cooperative positioning over GTSAM; `step()` once per epoch, in time order."""

    def __init__(self, config: FgoConfig | None = None) -> None:
        self.config = config or FgoConfig()
        self.reset()

    def reset(self) -> None:
        """Forget every state: the next epoch starts the window afresh."""
        self._state = GraphState(Window(self.config.window_epochs))
        self._solver = ClusterSolver(self.config, self._state)
        self._last_time: GpsTime | None = None
        self._seeds: dict[str, VehicleSeed] = {}

    def seed(self, seed: VehicleSeed) -> None:
        """Resume `seed.vehicle_id` from its state before a restart (used by its next new track)."""
        self._seeds[seed.vehicle_id] = seed

    @property
    def tracked_vehicles(self) -> list[str]:
        """Vehicles with at least one state in the window."""
        return self._state.window.vehicles()

    def step(self, epoch: EpochInput) -> FleetSolution:
        """Solve one fleet epoch; never raises on bad data (see the module docstring)."""
        t0 = time.perf_counter()
        cfg = self.config
        st = self._state
        stats = StepStats()
        reason = out_of_order_reason(epoch, self._last_time)
        if reason is not None:
            return skipped_epoch(epoch, self._last_time, reason, time.perf_counter() - t0)
        k = st.step
        t = epoch.time
        for blk in st.window.prune(k - cfg.window_epochs + 1):
            for key in blk.keys:
                st.values.erase(key)
            st.cov.pop(blk.pos_key, None)
        self._solver.forget(set(st.window.by_vehicle))

        valid = validate_epoch(epoch, planes=cfg.use_planes, ranges=cfg.use_ranging)
        stats.rejected.update(valid.rejected)
        stats.skipped.update(valid.skipped)
        preps: dict[str, Prepared] = {}
        seeded: dict[str, VehicleSeed] = {}
        for vid, v in valid.vehicles.items():
            if not st.window.by_vehicle.get(vid) and (sd := self._take_seed(vid, t)) is not None:
                seeded[vid] = sd  # a new track starts at the seed's prediction instead of the SPP
                v = dataclasses.replace(v, spp=self._predict(sd, v.velocity, t))
            got = prepare_vehicle(v, t, st, cfg, stats)
            if isinstance(got, str):
                stats.skipped[vid] = got
                seeded.pop(vid, None)
            else:
                preps[vid] = got
                if vid in seeded:
                    got.rank_self += 3  # the seed's prior determines the position
        for vid in preps:
            if not st.window.by_vehicle.get(vid):
                st.track_start[vid] = k  # a new track, from the SPP (or its seed)
        ranges = self._warm(valid.ranges_between(preps), k, stats)
        for vid in undetermined(preps, ranges):
            stats.skipped[vid] = "not enough measurements to determine a first position"
            del preps[vid]
        ranges = self._warm(valid.ranges_between(preps), k, stats)

        rec = StepRecord(k, t, {}, [])
        for vid in sorted(preps):
            blk = build_block(preps[vid], k, t, st.keys, cfg)
            if vid in seeded:
                self._add_seed_priors(blk, seeded[vid], preps[vid].velocity, preps[vid].drift, t)
            rec.blocks[vid] = blk
            st.values.insertPoint3(blk.pos_key, blk.init_pos)
            for ck, clock_s in blk.init_clocks.items():
                st.values.insert(ck, c=clock_s)  # keyword: pybind11 tries ~50 overloads for a float
        for r in ranges:
            ka, kb = rec.blocks[r.a].pos_key, rec.blocks[r.b].pos_key
            factor = F.range_factor(
                ka, kb, r.range_m, r.sigma_or(cfg.range_sigma), cfg.robust, cfg.robust_tuning
            )
            rec.ranges.append(RangeEdge(r.a, r.b, ka, kb, factor))
        st.window.push(rec)

        n_clusters = 0
        for view in st.window.partition(cfg.split_clusters):
            if not any(v in rec.blocks for v in view.vehicles):
                continue
            n_clusters += 1
            self._solver.solve(view, rec, stats)

        estimates = self._estimates(rec, t)
        counts = {kind: n for kind, n in sorted(st.window.counts.items()) if n}
        if stats.anchors:
            counts["anchor"] = stats.anchors
        st.step += 1
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
            rejected={kind: n for kind, n in sorted(stats.rejected.items()) if n},
            n_clusters=n_clusters,
        )

    def _take_seed(self, vid: str, t: GpsTime) -> VehicleSeed | None:
        """The vehicle's seed if it is usable at `t` (before `t`, not too old); used at most once."""
        sd = self._seeds.pop(vid, None)
        if sd is None or not (sd.time < t) or t - sd.time > SEED_MAX_AGE_S:
            return None
        return sd

    @staticmethod
    def _predict(sd: VehicleSeed, velocity: np.ndarray | None, t: GpsTime) -> np.ndarray:
        dt = t - sd.time
        p = np.asarray(sd.position_m, dtype=float)
        return p + velocity * dt if velocity is not None else p

    def _add_seed_priors(
        self, blk: StateBlock, sd: VehicleSeed, velocity: np.ndarray | None, drift: float | None, t: GpsTime
    ) -> None:
        """Position and clock priors from the seed on the block's own variables (they leave the
        window with the block). Without a velocity the position may have moved max_speed * dt."""
        cfg = self.config
        dt = t - sd.time
        grow = (cfg.sigma_v if velocity is not None else cfg.max_speed) * dt
        cov = None if sd.covariance_m2 is None else np.asarray(sd.covariance_m2, dtype=float).reshape(3, 3)
        cov = F.floored_covariance(None if cov is None else cov + np.eye(3) * grow**2, cfg.anchor_sigma)
        blk.graph.add(F.position_prior(blk.pos_key, self._predict(sd, velocity, t), cov))
        n = 1
        for system, ck in blk.clock_keys.items():
            if system not in sd.clocks_s or ck not in blk.init_clocks:
                continue
            step_m = (drift or 0.0) * dt
            sigma_m = F.clock_step_sigma_m(dt, drift is not None, cfg.clock_rw_sigma, cfg.clock_drift_sigma)
            mean_m = C * sd.clocks_s[system] + step_m
            if abs(C * blk.init_clocks[ck] - mean_m) > max(cfg.clock_jump_m, 5.0 * sigma_m):
                continue  # the receiver clock jumped while the server was down: no clock prior
            blk.graph.add(F.clock_prior(ck, mean_m / C, sigma_m / C))
            n += 1
        blk.counts["seed"] = blk.counts.get("seed", 0) + n

    def _warm(self, ranges: list[ValidRange], k: int, stats: StepStats) -> list[ValidRange]:
        """Ranges, without the short ones of vehicles tracked for less than `range_warmup_epochs`."""
        w, short = self.config.range_warmup_epochs, self.config.range_warmup_max_m
        if w == 0:
            return ranges
        start = self._state.track_start
        keep = [r for r in ranges if r.range_m >= short or (k - start[r.a] >= w and k - start[r.b] >= w)]
        if len(keep) < len(ranges):
            stats.reject("range_warmup", len(ranges) - len(keep))
        return keep

    def _estimates(self, rec: StepRecord, t: GpsTime) -> dict[str, VehicleEstimate]:
        """The newest state of every vehicle solved this epoch."""
        st = self._state
        n_ranges: dict[str, int] = {}
        for r in rec.ranges:
            n_ranges[r.a] = n_ranges.get(r.a, 0) + 1
            n_ranges[r.b] = n_ranges.get(r.b, 0) + 1
        nan_cov = np.full((3, 3), np.nan)
        estimates: dict[str, VehicleEstimate] = {}
        for vid in sorted(rec.blocks):
            blk = rec.blocks[vid]
            estimates[vid] = VehicleEstimate(
                vehicle_id=vid,
                time=t,
                position_m=st.position(blk.pos_key),
                covariance_m2=st.cov.get(blk.pos_key, nan_cov) * self.config.covariance_scale**2,
                clocks_s={s: st.clock(ck) for s, ck in blk.clock_keys.items()},
                n_pseudoranges=blk.n_pseudoranges,
                n_ranges=n_ranges.get(vid, 0),
                plane_used=blk.plane_used,
                has_gnss_fix=blk.has_fix,
            )
        return estimates
