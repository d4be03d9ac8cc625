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
enters the window as that vehicle's newest state (position and covariance as logged, clocks), in
a step of its own before the next epoch; the vehicle's next state then links to it like to any
earlier one (motion and clock links, gating and FDE at the prediction), so its track continues
instead of restarting from SPP alone.
"""

from __future__ import annotations

import time

import numpy as np

from coplane.estimation.contract import EpochInput, FleetSolution, VehicleEstimate, VehicleSeed, left_out
from coplane.estimation.validate import ValidRange, out_of_order_reason, skipped_epoch, validate_epoch
from coplane.fgo import factors as F
from coplane.fgo.blocks import build_block
from coplane.fgo.config import FgoConfig
from coplane.fgo.cooperative import cooperative_exclusion
from coplane.fgo.height_links import height_links
from coplane.fgo.keys import CLOCK_CHR, clock_key, position_key
from coplane.fgo.prepare import Prepared, prepare_vehicle, undetermined
from coplane.fgo.recipes import Recipe
from coplane.fgo.smoother import LocalSmoothers
from coplane.fgo.solve import ClusterSolver, Smoothers
from coplane.fgo.state import GraphState, StepStats
from coplane.fgo.window import RangeEdge, StateBlock, StepRecord, Window
from coplane.gnss.constants import C
from coplane.gtime import GpsTime
from coplane.numeric import norm3

SEED_MAX_AGE_S = 60.0  # a seed older than this (GPS time) says little about where the vehicle is
SEED_FLOOR_M = 0.05  # smallest sigma of a seed's position prior (m): never a hard constraint
SEED_CLOCK_FLOOR_M = 1.0  # smallest sigma of a seed's clock prior (m of range)


class FusionEstimator:
    """Sliding-window cooperative positioning over GTSAM; `step()` once per epoch, in time order."""

    def __init__(self, config: FgoConfig | None = None, smoothers: Smoothers | None = None) -> None:
        """`smoothers`: where the clusters' smoothers run, e.g. `coplane.parallel.SmootherPool`
        for several processes (the same estimates); default: in this process."""
        self.config = config or FgoConfig()
        self._smoothers: Smoothers = smoothers if smoothers is not None else LocalSmoothers(self.config)
        # this process solves every cluster: build each factor as it is made and keep no recipe
        # (the recipes' arguments serve only to ship a factor to another process)
        self._settle = isinstance(self._smoothers, LocalSmoothers)
        self.reset()

    def reset(self) -> None:
        """Forget every state: the next epoch starts the window afresh."""
        self._smoothers.keep(set())
        self._state = GraphState(Window(self.config.window_epochs))
        self._solver = ClusterSolver(self.config, self._state, self._smoothers)
        self._last_time: GpsTime | None = None
        self._interval_s: float | None = None  # the smallest epoch interval seen
        self._seeds: dict[str, VehicleSeed] = {}

    @property
    def workers(self) -> tuple[int, int]:
        """(processes the clusters are solved on, how many of them died): for diagnostics."""
        return self._smoothers.status()

    def close(self) -> None:
        """Stop the smoothers' worker processes, if any; the estimator is unusable after."""
        self._smoothers.close()

    def seed(self, seed: VehicleSeed) -> None:
        """Resume `seed.vehicle_id` from its state before a restart (used by its next new track)."""
        self._seeds[seed.vehicle_id] = seed

    @property
    def tracked_vehicles(self) -> list[str]:
        """Vehicles with at least one state in the window."""
        return self._state.window.vehicles()

    def tracked_at(self, t: GpsTime) -> list[str]:
        """Vehicles that will still have a state in the window at epoch `t`: the others need a
        seed (or their SPP) to start again, even if stale states of theirs are still held."""
        st = self._state
        oldest = st.step + self._missed_epochs(t, learn=False) - self.config.window_epochs + 1
        return sorted(v for v, dq in st.window.by_vehicle.items() if dq and dq[-1].step >= oldest)

    def step(self, epoch: EpochInput) -> FleetSolution:
        """Solve one fleet epoch; never raises on bad data (see the module docstring)."""
        t0 = time.perf_counter()
        cfg = self.config
        st = self._state
        stats = StepStats()
        reason = out_of_order_reason(epoch, self._last_time)
        if reason is not None:
            return skipped_epoch(epoch, self._last_time, reason, time.perf_counter() - t0)
        st.step += self._missed_epochs(epoch.time)
        if self._seeds:
            self._push_seeds(epoch.time)  # takes one step index of its own
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
        for vid, v in valid.vehicles.items():
            got = prepare_vehicle(v, t, st, cfg, stats)
            if isinstance(got, str):
                stats.skipped[vid] = got
            else:
                preps[vid] = got
        if cfg.coop_fde_k is not None:
            cooperative_exclusion(preps, cfg.coop_fde_k, cfg.coop_fde_radius_m, stats)
        for vid in preps:
            if not st.window.by_vehicle.get(vid) or preps[vid].restarted:
                st.track_start[vid] = k  # a new track: from the SPP, or restarted at the epoch's fit
        ranges, held = self._warm(valid.ranges_between(preps), preps, k)
        for vid in undetermined(preps, ranges):
            stats.skipped[vid] = "not enough measurements to determine a first position"
            del preps[vid]
        # a verdict depends only on a range's two ends: keep (and count) those of the vehicles left
        ranges = [r for r in ranges if r.a in preps and r.b in preps]
        n_held = sum(1 for r in held if r.a in preps and r.b in preps)
        if n_held:
            stats.reject("range_warmup", n_held)
        if cfg.split_clusters:
            kept = st.window.bounded(ranges, preps, cfg.window_cluster_max)
            if len(kept) < len(ranges):
                stats.reject("range_cluster_bound", len(ranges) - len(kept))
            ranges = kept

        rec = StepRecord(k, t, {}, [])
        for vid in sorted(preps):
            # after every exclusion (FDE, cooperative check, dead reckoning): what the user sees
            preps[vid].excluded = left_out(valid.vehicles[vid].pseudoranges.sats, preps[vid].prs.sats)
            blk = build_block(preps[vid], k, t, st.keys, cfg)
            if self._settle:
                blk.settle()
            rec.blocks[vid] = blk
            st.values.insertPoint3(blk.pos_key, blk.init_pos)
            for ck, clock_s in blk.init_clocks.items():
                st.values.insert(ck, c=clock_s)  # keyword: pybind11 tries ~50 overloads for a float
        kernel = (cfg.robust, cfg.robust_tuning)
        for r in ranges:
            ka, kb = rec.blocks[r.a].pos_key, rec.blocks[r.b].pos_key
            sigma = r.sigma_or(cfg.range_sigma)
            edge = RangeEdge(r.a, r.b, ka, kb, "range", F.range_factor, ka, kb, r.range_m, sigma, *kernel)
            rec.ranges.append(edge)
        if cfg.use_planes and cfg.height_link_max_m > 0:
            n_set = cfg.height_link_settled_epochs
            rec.ranges += height_links(
                ranges, rec.blocks, valid.vehicles, cfg, lambda v: k - st.track_start[v] >= n_set
            )
        if self._settle:
            for edge in rec.ranges:
                edge.settle()
        st.window.push(rec)

        views = [
            w for w in st.window.partition(cfg.split_clusters) if any(v in rec.blocks for v in w.vehicles)
        ]
        self._solver.solve_all(views, rec, stats)
        n_clusters = len(views)

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

    def _missed_epochs(self, t: GpsTime, learn: bool = True) -> int:
        """Epochs of time since the last step that brought no call (0 normally).

        The window holds the last `window_epochs` epochs of *time*: the step counter skips the
        epochs nobody asked about, so states older than the window leave it (marginalised by the
        smoothers) even when the estimator was not called for a while: a region's server whose
        vehicles were elsewhere, a stream that stalled. Otherwise the next epoch would link to a
        state from minutes ago as if it were the previous one."""
        if self._last_time is None:
            return 0
        dt = t - self._last_time
        if not dt > 0.0:
            return 0
        if self._interval_s is None or dt < self._interval_s:
            if learn:
                self._interval_s = dt
            return 0
        return max(0, int(dt / self._interval_s + 0.5) - 1)

    def _push_seeds(self, t: GpsTime) -> None:
        """Put the usable seeds into the window as one step of their own, before epoch `t`.

        Each seed becomes its vehicle's newest state: its position and clocks as values, its
        covariance as the state's reported covariance, and priors at those values (position with
        that covariance, clocks loose). The vehicle's next epoch then links to it like to any
        earlier state: motion and clock links, gating and FDE at the prediction, anchors.
        """
        cfg, st = self.config, self._state
        seeds = {
            vid: sd
            for vid, sd in sorted(self._seeds.items())
            if sd.time < t and t - sd.time <= SEED_MAX_AGE_S and not st.window.by_vehicle.get(vid)
        }
        self._seeds.clear()
        if not seeds:
            return
        k = st.step
        for blk in st.window.prune(k - cfg.window_epochs + 1):
            for key in blk.keys:
                st.values.erase(key)
            st.cov.pop(blk.pos_key, None)
        rec = StepRecord(k, max(sd.time for sd in seeds.values()), {}, [])
        for vid, sd in seeds.items():
            blk = self._seed_block(sd, k)
            rec.blocks[vid] = blk
            st.values.insertPoint3(blk.pos_key, blk.init_pos)
            for ck, clock_s in blk.init_clocks.items():
                st.values.insert(ck, c=clock_s)
            st.track_start[vid] = k
        st.window.push(rec)
        st.step += 1

    def _seed_block(self, sd: VehicleSeed, k: int) -> StateBlock:
        cfg, st = self.config, self._state
        slot = st.keys.slot(sd.vehicle_id)
        pk = position_key(slot, k)
        pos = np.asarray(sd.position_m, dtype=float)
        cov = None if sd.covariance_m2 is None else np.asarray(sd.covariance_m2, dtype=float).reshape(3, 3)
        if cov is not None:
            # a seed is a reported state: its covariance carries `covariance_scale` (an honest
            # error bound); the graph's own information is that divided out (the common errors'
            # term, when reported, stays in: a looser seed, never a tighter one)
            cov = cov / self.config.covariance_scale**2
        cov = F.floored_covariance(cov, SEED_FLOOR_M if cov is not None else cfg.anchor_sigma)
        st.cov[pk] = cov
        seed = [Recipe(F.position_prior, pk, pos, cov)]
        clocks = {s: c for s, c in sorted(sd.clocks_s.items()) if s in CLOCK_CHR}
        cks = {s: clock_key(slot, k, s) for s in clocks}
        # the log has no clock covariance: the position's, which GNSS geometry ties to the clock
        clock_sigma_m = max(SEED_CLOCK_FLOOR_M, float(np.sqrt(np.trace(cov))))
        for s, ck in cks.items():
            seed.append(Recipe(F.clock_prior, ck, clocks[s], clock_sigma_m / C))
        return StateBlock(
            vehicle_id=sd.vehicle_id,
            step=k,
            time=sd.time,
            pos_key=pk,
            clock_keys=cks,
            init_pos=pos,
            init_clocks={cks[s]: c for s, c in clocks.items()},
            recipes=seed,
            counts={"seed": 1 + len(cks)},
            links=[],
            n_pseudoranges=0,
            plane_used=False,
            velocity=None,
            clock_drift_mps=None,
            has_fix=False,
        )

    def _warm(
        self, ranges: list[ValidRange], preps: dict[str, Prepared], k: int
    ) -> tuple[list[ValidRange], list[ValidRange]]:
        """The ranges admitted now, and those held back: short ones that could lock two swapped
        first fixes in place.

        A range fixes a distance, not a side: two vehicles a few metres apart whose first fixes are
        swapped stay swapped once it holds them. Only two unsettled ends (both tracked for less than
        `range_warmup_epochs`) can be swapped; a settled end anchors the range. And fixes whose
        distance differs from the range by more than `range_warmup_max_m` (the SPP error scale) are
        not a swap but a far-off fix, which the range pulls in: it is admitted at once."""
        w, short = self.config.range_warmup_epochs, self.config.range_warmup_max_m
        if w == 0:
            return ranges, []
        start = self._state.track_start

        def admitted(r: ValidRange) -> bool:
            if r.range_m >= short or k - start[r.a] >= w or k - start[r.b] >= w:
                return True
            gap = norm3(preps[r.a].init_pos - preps[r.b].init_pos) - r.range_m
            return abs(gap) > short

        keep: list[ValidRange] = []
        held: list[ValidRange] = []
        for r in ranges:
            (keep if admitted(r) else held).append(r)
        return keep, held

    def _estimates(self, rec: StepRecord, t: GpsTime) -> dict[str, VehicleEstimate]:
        """The newest state of every vehicle solved this epoch."""
        st = self._state
        n_ranges: dict[str, int] = {}
        for r in (e for e in rec.ranges if e.kind == "range"):
            n_ranges[r.a] = n_ranges.get(r.a, 0) + 1
            n_ranges[r.b] = n_ranges.get(r.b, 0) + 1
        nan_cov = np.full((3, 3), np.nan)
        estimates: dict[str, VehicleEstimate] = {}
        for vid in sorted(rec.blocks):
            blk = rec.blocks[vid]
            cov = st.cov.get(blk.pos_key, nan_cov) * self.config.covariance_scale**2
            if blk.common_cov is not None:  # the errors the window cannot average (common_error)
                cov = cov + blk.common_cov * self.config.covariance_common_scale**2
            estimates[vid] = VehicleEstimate(
                vehicle_id=vid,
                time=t,
                position_m=st.position(blk.pos_key),
                covariance_m2=cov,
                clocks_s=_clocks(st, blk),
                n_pseudoranges=blk.n_pseudoranges,
                n_ranges=n_ranges.get(vid, 0),
                plane_used=blk.plane_used,
                has_gnss_fix=blk.has_fix,
                excluded_satellites=blk.excluded,
            )
        return estimates


def _clocks(st: GraphState, blk: StateBlock) -> dict[str, float]:
    """Each system's receiver clock (seconds): its own variable, or the receiver clock less the
    system's offset (`FgoConfig.clock_isb_sigma_m`), systems sorted."""
    out = {s: st.clock(ck) for s, ck in blk.clock_keys.items()}
    if blk.clock_ref is not None:
        ref = out[blk.clock_ref]
        out |= {s: ref - st.clock(bk) / C for s, bk in blk.bias_keys.items()}
    return dict(sorted(out.items()))
