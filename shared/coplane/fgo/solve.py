"""Solving one cluster of the window with the configured solver, and recovering when GTSAM fails.

A cluster is a set of vehicles linked by ranges within the window (`Window.partition`). With
`lm-window` it is solved from scratch each epoch with loose anchor priors on the oldest states;
with a fixed-lag smoother (`isam2-fixed-lag`, `batch-fixed-lag`) each cluster keeps a smoother
that is fed only the new epoch, and is rebuilt from the window when the cluster merges, splits
(`FgoConfig.isam2_keep_on_split`: all but its largest part) or an update fails
(`coplane.fgo.slots`). A GTSAM failure is retried once with strong priors on
every state; if that fails too, the cluster's new epoch is dropped (`ClusterFailure`), never the
estimator.
"""

from __future__ import annotations

from collections.abc import Generator, Sequence
from typing import Protocol

import gtsam
import numpy as np

from coplane.fgo import factors as F
from coplane.fgo.config import FgoConfig
from coplane.fgo.gnc import solve_gnc_window
from coplane.fgo.recipes import Recipe
from coplane.fgo.slots import Slot, keepers
from coplane.fgo.smoother import LocalSmoothers, SmootherTask
from coplane.fgo.state import GraphState, StepStats
from coplane.fgo.window import ClusterResult, ClusterView, StateBlock, StepRecord, solve_lm_window
from coplane.gnss.constants import C

FALLBACK_CLOCK_SIGMA_S = 1e-3  # strong-prior retry: clocks only need regularising
ANCHOR_CLOCK_SIGMA_M = 1000.0  # the window's first receiver clock when the systems share one


class ClusterFailure(RuntimeError):
    """GTSAM could not solve a cluster, even with strong priors."""


class Smoothers(Protocol):
    """Where the clusters' smoothers live and run: `LocalSmoothers` or `coplane.parallel.SmootherPool`."""

    def run(self, tasks: Sequence[SmootherTask]) -> list[ClusterResult | Exception]: ...

    def status(self) -> tuple[int, int]: ...

    def keep(self, slots: set[int]) -> None: ...

    def close(self) -> None: ...


Outcome = ClusterResult | ClusterFailure
Attempts = Generator[SmootherTask, ClusterResult | Exception, ClusterResult]


class ClusterSolver:
    """Solves the clusters of each epoch and writes estimates and covariances into the state.

    The smoothers live in `smoothers`: this process (`LocalSmoothers`) or a pool of processes
    (`coplane.parallel.SmootherPool`). Either way every cluster's epoch is solved from the same
    graphs, and the results are written back in cluster order, so the estimates are the same.
    """

    def __init__(self, cfg: FgoConfig, state: GraphState, smoothers: Smoothers | None = None) -> None:
        self.cfg = cfg
        self.state = state
        self.smoothers: Smoothers = smoothers if smoothers is not None else LocalSmoothers(cfg)
        self._slots: list[Slot] = []
        self._next_slot = 0

    def forget(self, in_window: set[str]) -> None:
        """Smoothers keep only vehicles still in the window; empty ones are dropped."""
        for slot in self._slots:
            slot.vehicles &= in_window
        self._slots = [s for s in self._slots if s.vehicles]

    def solve_all(self, views: Sequence[ClusterView], rec: StepRecord, stats: StepStats) -> None:
        """Solve the epoch's clusters and store their results; a failed one drops its new states.

        Each cluster's attempts (update its smoother, else rebuild, else rebuild with strong
        priors) run in rounds: one task per unfinished cluster, all handed to the smoothers at
        once so that a pool solves them side by side. Clusters share no state, so the rounds
        give what solving them one after the other gives.
        """
        outcomes: dict[int, Outcome] = {}
        if self.cfg.solver == "lm-window":
            for i, view in enumerate(views):
                outcomes[i] = self._solve_lm(view, rec, stats)
        else:
            keeps = keepers(self.cfg, self._slots, views, self.state.window.by_vehicle, self.state.step)
            attempts = {i: self._attempts(view, rec, stats, keeps.get(i)) for i, view in enumerate(views)}
            tasks = {i: next(gen) for i, gen in attempts.items()}
            while tasks:
                order = sorted(tasks)
                results = self.smoothers.run([tasks[i] for i in order])
                tasks = {}
                for i, res in zip(order, results, strict=True):
                    try:
                        tasks[i] = attempts[i].send(res)
                    except StopIteration as done:
                        outcomes[i] = done.value
                    except ClusterFailure as exc:
                        outcomes[i] = exc
        for i, view in enumerate(views):
            self._store(view, rec, outcomes[i], stats)
        self.smoothers.keep({s.id for s in self._slots})

    def _store(self, view: ClusterView, rec: StepRecord, res: Outcome, stats: StepStats) -> None:
        if isinstance(res, ClusterFailure):
            new = [v for v in view.vehicles if v in rec.blocks]
            self._drop_new(new, rec, f"solver failed, epoch dropped: {res}", stats)
            self._slots = [s for s in self._slots if not (s.vehicles & set(view.vehicles))]
            return
        self.state.values.update(res.values)
        for key, cov in res.covariances.items():
            self.state.cov[key] = 0.5 * (cov + cov.T)
        stats.iterations = max(stats.iterations, res.iterations)
        stats.error_before += res.error_before
        stats.error_after += res.error_after

    # ------------------------------------------------------------------------------------------

    def _initial(self, blocks: Sequence[StateBlock]) -> gtsam.Values:
        return self.state.values.extract([key for b in blocks for key in b.keys])

    def _anchors(self, vehicles: Sequence[str]) -> list[Recipe]:
        """Loose priors on each vehicle's oldest window state that was solved before.

        Mean: its latest estimate. Covariance: what was reported for it when it was the newest
        state (a filtered, hence conservative, marginal) with eigenvalues floored at
        anchor_sigma^2: negligible next to GNSS in the window, and during an outage longer than the
        window it grows like dead reckoning instead of pinning the vehicle.
        """
        st = self.state
        out: list[Recipe] = []
        for v in vehicles:
            oldest = st.window.by_vehicle[v][0]
            if oldest.step == st.step:
                continue  # created this epoch: nothing to anchor to
            cov = F.floored_covariance(st.cov.get(oldest.pos_key), self.cfg.anchor_sigma)
            out.append(Recipe(F.position_prior, oldest.pos_key, st.position(oldest.pos_key), cov))
            # one receiver clock (FgoConfig.clock_isb_sigma_m) that epochs without its system's
            # satellites carry: only its differences to the offsets are observed there, so the
            # window's first such clock needs a value (loose: 1 km) once its link has left
            first = next((b for b in st.window.by_vehicle[v] if b.clock_ref is not None), None)
            if first is not None and first.clock_ref is not None and first.step != st.step:
                ck = first.clock_keys[first.clock_ref]
                out.append(Recipe(F.clock_prior, ck, st.clock(ck), ANCHOR_CLOCK_SIGMA_M / C))
        return out

    def _strong_priors(self, blocks: Sequence[StateBlock]) -> list[Recipe]:
        """Retry after a GTSAM failure: every state gets a prior at its current value."""
        cov = np.eye(3) * self.cfg.anchor_sigma**2
        out: list[Recipe] = []
        for b in blocks:
            out.append(Recipe(F.position_prior, b.pos_key, self.state.position(b.pos_key), cov))
            for ck in b.clock_keys.values():
                out.append(Recipe(F.clock_prior, ck, self.state.clock(ck), FALLBACK_CLOCK_SIGMA_S))
            for bk in b.bias_keys.values():  # offsets from the receiver clock, metres
                out.append(Recipe(F.clock_prior, bk, self.state.clock(bk), FALLBACK_CLOCK_SIGMA_S * C))
        return out

    def _drop_new(self, vehicles: Sequence[str], rec: StepRecord, reason: str, stats: StepStats) -> None:
        for v in vehicles:
            blk = rec.blocks.get(v)
            if blk is None:
                continue
            for key in blk.keys:
                self.state.values.erase(key)
            stats.skipped[v] = reason
        self.state.window.drop_new(vehicles)

    def _cov_keys(self, view: ClusterView, rec: StepRecord) -> list[int]:
        if not self.cfg.compute_covariance:
            return []
        return [rec.blocks[v].pos_key for v in view.vehicles if v in rec.blocks]

    def _solve_lm(self, view: ClusterView, rec: StepRecord, stats: StepStats) -> Outcome:
        cfg = self.cfg
        oldest = self.state.step - cfg.window_epochs + 1
        anchors = self._anchors(view.vehicles)
        initial = self._initial(view.blocks)
        cov_keys = self._cov_keys(view, rec)
        solve = solve_lm_window if cfg.gnc is None else solve_gnc_window
        try:
            res = solve(cfg, view.blocks, view.ranges, anchors, initial, cov_keys, oldest)
        except Exception:  # GTSAM raises RuntimeError subclasses (IndeterminantLinearSystem...)
            try:
                priors = anchors + self._strong_priors(view.blocks)
                res = solve(cfg, view.blocks, view.ranges, priors, initial, cov_keys, oldest)
            except Exception as exc:
                return ClusterFailure(short_error(exc))
        stats.anchors += len(anchors)
        return res

    def _attempts(self, view: ClusterView, rec: StepRecord, stats: StepStats, keep: Slot | None) -> Attempts:
        """Feed the cluster's smoother the new epoch, or (re)build one from the window.

        A cluster that keeps a smoother (`slots.keepers`) feeds it the new epoch. Any other (a
        merge, a split's other parts, a vehicle whose earlier states belong to no smoother), or a
        failed update, rebuilds it from the window with the same anchor priors as lm-window, since
        what was marginalised cannot be moved between smoothers. Yields each attempt's task and
        receives its result.
        """
        cfg = self.cfg
        k = self.state.step
        by_vehicle = self.state.window.by_vehicle
        members = set(view.vehicles)
        cov_keys = self._cov_keys(view, rec)
        oldest = k - cfg.window_epochs + 1
        keys = [key for b in view.blocks for key in b.keys]
        if keep is not None:
            blocks = [rec.blocks[v] for v in view.vehicles if v in rec.blocks]
            ranges = [r for r in rec.ranges if r.a in members]
            stamps = {key: float(k) for b in blocks for key in b.keys}
            fresh = any(len(by_vehicle[b.vehicle_id]) == 1 for b in blocks)  # from SPP
            initial = self._initial(blocks)
            res = yield SmootherTask(
                keep.id,
                False,
                view.vehicles,
                blocks,
                ranges,
                [],
                initial,
                stamps,
                cov_keys,
                oldest,
                keys,
                fresh,
            )
            if not isinstance(res, Exception):
                keep.vehicles = set(members)  # a split's other parts were rebuilt
                return res
            keep.vehicles.clear()  # its smoother was dropped with the failed update: rebuild
        slots = [s for s in self._slots if s.vehicles & members]
        for s in slots:
            s.vehicles -= members
            if not self.cfg.isam2_keep_on_split:
                s.dirty = True  # what remains of it was split off: rebuild before solving it again
        self._slots = [s for s in self._slots if s.vehicles]
        anchors = self._anchors(view.vehicles)
        stamps = {key: float(b.step) for b in view.blocks for key in b.keys}
        initial = self._initial(view.blocks)
        last: Exception | None = None
        # the strong priors only for a retry: made on every rebuild, they cost about 1 % of a city
        for retry in (False, True):
            priors = anchors + self._strong_priors(view.blocks) if retry else anchors
            sid = self._next_slot
            self._next_slot += 1
            res = yield SmootherTask(
                sid,
                True,
                view.vehicles,
                view.blocks,
                view.ranges,
                priors,
                initial,
                stamps,
                cov_keys,
                oldest,
                keys,
                True,
            )
            if isinstance(res, Exception):
                last = res
                continue
            self._slots.append(Slot(sid, set(members)))
            stats.anchors += len(anchors)
            return res
        assert last is not None
        raise ClusterFailure(short_error(last))


def short_error(exc: BaseException) -> str:
    """The first line of an exception, for a `skipped` reason."""
    text = f"{type(exc).__name__}: {exc}".strip()
    first = text.splitlines()[0] if text else type(exc).__name__
    return first[:200]
