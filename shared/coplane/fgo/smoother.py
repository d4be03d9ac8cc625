"""One cluster's fixed-lag smoother, and the smoothers of every cluster kept in this process.

`SmootherCluster` wraps GTSAM's iSAM2 (or batch LM) fixed-lag smoother for the vehicles of one
cluster. Its `update` builds the graph of what is new (the whole window on a rebuild, else one
epoch) and `solve_graph` feeds it to GTSAM: the split lets a pool of worker processes
(`coplane.parallel`) receive the recipes of a graph (`coplane.fgo.recipes`) and build and solve
it where the smoother lives.

`SmootherTask` is one attempt at solving a cluster's epoch with the smoother of one slot;
`LocalSmoothers` runs tasks on smoothers held in this process (the default, one core);
`coplane.parallel.SmootherPool` runs them on several.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, cast

import gtsam
import numpy as np
from numpy.typing import NDArray

from coplane.fgo.config import FgoConfig
from coplane.fgo.keys import relinearize_thresholds
from coplane.fgo.recipes import Recipe
from coplane.fgo.window import (
    ClusterResult,
    RangeEdge,
    StateBlock,
    build_graph,
    lm_params,
    marginal_covariances,
)
from coplane.numeric import norm3


class SmootherCluster:
    """One cluster's GTSAM fixed-lag smoother (iSAM2 or batch LM), timestamps = epoch steps."""

    def __init__(self, cfg: FgoConfig, vehicles: Sequence[str] | set[str]) -> None:
        self.cfg = cfg
        self.vehicles: set[str] = set(vehicles)
        self.incremental = cfg.solver == "isam2-fixed-lag"
        self.smoother: gtsam.IncrementalFixedLagSmoother | gtsam.BatchFixedLagSmoother
        if self.incremental:
            p = gtsam.ISAM2Params()
            p.setRelinearizeThreshold(relinearize_thresholds(cfg.isam2_relinearize_threshold))
            # iSAM2 checks relinearisation on every cycle's first update (`_update`)
            p.relinearizeSkip = int(cfg.isam2_cycle_updates)
            p.enablePartialRelinearizationCheck = cfg.isam2_partial_relinearization_check
            p.findUnusedFactorSlots = True
            # IncrementalFixedLagSmoother's result never carries iSAM2's error (getError() is 0
            # whatever the graph), so evaluating it (the whole graph at two full estimates per
            # update) was CPU spent for nothing; the estimates are checked for divergence instead
            # (`solve_graph`)
            p.evaluateNonlinearError = False
            self.smoother = gtsam.IncrementalFixedLagSmoother(cfg.lag, p)
        else:
            self.smoother = gtsam.BatchFixedLagSmoother(cfg.lag, lm_params(cfg))
        self._updates = 0  # iSAM2's own count of its updates, which it does not show

    def update(
        self,
        blocks: Sequence[StateBlock],
        ranges: Sequence[RangeEdge],
        priors: Sequence[Recipe],
        initial: gtsam.Values,
        timestamps: dict[int, float],
        cov_keys: Sequence[int],
        oldest_step: int,
        estimate_keys: Sequence[int],
        converge: bool = False,
    ) -> ClusterResult:
        """Add factors and new variables (the whole window on creation, else one epoch).

        Returns the estimates of `estimate_keys` (the cluster's window states) only: the smoother
        may still hold states the window already dropped, until its next marginalisation.
        """
        graph = build_graph(blocks, ranges, priors, oldest_step)
        pos_keys = [b.pos_key for b in blocks]
        return self.solve_graph(graph, initial, timestamps, cov_keys, estimate_keys, pos_keys, converge)

    def solve_graph(
        self,
        graph: gtsam.NonlinearFactorGraph,
        initial: gtsam.Values,
        timestamps: dict[int, float],
        cov_keys: Sequence[int],
        estimate_keys: Sequence[int],
        pos_keys: Sequence[int],
        converge: bool,
    ) -> ClusterResult:
        """Feed GTSAM the new factors and values; with `converge`, iterate until `pos_keys` settle."""
        res = self._update(graph, initial, timestamps)
        iterations = int(res.getIterations())
        keys = list(estimate_keys)
        if self.incremental:
            for _ in range(self.cfg.isam2_extra_iterations):
                self._relinearize()
                iterations += 1
            if converge:
                # iSAM2 makes one Gauss-Newton step per update: from an SPP start (new cluster or
                # vehicle) iterate until the positions settle, as batch LM would
                before = self.smoother.calculateEstimate(list(pos_keys))
                for _ in range(self.cfg.isam2_converge_iterations):
                    self._relinearize()
                    iterations += 1
                    after = self.smoother.calculateEstimate(list(pos_keys))
                    moved = max(norm3(after.atPoint3(k) - before.atPoint3(k)) for k in pos_keys)
                    before = after
                    if moved < self.cfg.isam2_converged_m:
                        break
        values = self.smoother.calculateEstimate(keys)
        if not np.isfinite(gtsam.utilities.extractPoint3(values)).all():
            raise RuntimeError("smoother returned a non-finite position")
        error = float("nan")  # iSAM2's result has no error (not evaluated); batch LM's has
        if not self.incremental:
            error = float(res.getError())
            if not np.isfinite(error):
                raise RuntimeError(f"smoother returned a non-finite error {error}")
        covs = self.covariances(cov_keys) if cov_keys else {}
        return ClusterResult(values, covs, iterations, float("nan"), error)

    def _update(
        self, graph: gtsam.NonlinearFactorGraph, initial: gtsam.Values, timestamps: dict[int, float]
    ) -> gtsam.FixedLagSmootherResult:
        """Add an epoch's factors; iSAM2 marginalises and relinearises on one update per cycle only.

        Marginalising re-eliminates iSAM2's whole Bayes tree, and so does relinearising the many
        states each epoch moves by centimetres; the other updates of a cycle re-eliminate only the
        newest epochs (`FgoConfig.isam2_cycle_updates`). Between those updates the lag is stretched
        by a cycle, so the states that left the window leave the smoother together.
        """
        if self.incremental:
            # iSAM2 counts the update first, then relinearises when its count is a multiple of
            # relinearizeSkip (GTSAM 4.3's ISAM2::update): marginalise on that same update
            self._updates += 1
            cycle = int(self.cfg.isam2_cycle_updates)
            on_cycle = self._updates % cycle == 0
            self.smoother.setSmootherLag(self.cfg.lag if on_cycle else self.cfg.lag + cycle)
        return self.smoother.update(graph, initial, cast(Any, timestamps))

    def _relinearize(self) -> None:
        """One more iSAM2 step without new factors, relinearising whatever moved beyond the threshold.

        Straight to the iSAM2 (`getISAM2` is the smoother's own, not a copy): with no new factors
        the fixed-lag smoother has nothing to marginalise or stamp, and only iSAM2 takes
        `force_relinearize`, which a converging new cluster needs between cycles.
        """
        sm = self.smoother
        assert isinstance(sm, gtsam.IncrementalFixedLagSmoother)  # only iSAM2 iterates this way
        self._updates += 1
        sm.getISAM2().update(gtsam.NonlinearFactorGraph(), gtsam.Values(), [], None, None, None, True)

    def covariances(self, keys: Sequence[int]) -> dict[int, NDArray[np.float64]]:
        """Marginal covariances: iSAM2 has them in its Bayes tree; batch needs gtsam.Marginals."""
        sm = self.smoother
        if isinstance(sm, gtsam.IncrementalFixedLagSmoother):
            return marginal_covariances(sm.getISAM2(), keys)
        graph = _non_null(sm.getFactors())
        return marginal_covariances(gtsam.Marginals(graph, self.smoother.calculateEstimate()), keys)


def _non_null(graph: gtsam.NonlinearFactorGraph) -> gtsam.NonlinearFactorGraph:
    """The smoother's factor graph without the empty slots left by marginalisation."""
    out = gtsam.NonlinearFactorGraph()
    for i in range(graph.size()):
        if graph.exists(i):
            out.add(graph.at(i))
    return out


@dataclass
class SmootherTask:
    """One attempt at a cluster's epoch: the new epoch for an existing smoother (`create` False)
    or the whole window for a new one, in slot `slot`."""

    slot: int
    create: bool
    vehicles: list[str]
    blocks: Sequence[StateBlock]
    ranges: Sequence[RangeEdge]
    priors: Sequence[Recipe]
    initial: gtsam.Values
    timestamps: dict[int, float]
    cov_keys: list[int]
    oldest_step: int
    estimate_keys: list[int]
    converge: bool


class LocalSmoothers:
    """The smoothers of every slot, in this process: tasks run one after the other."""

    def __init__(self, cfg: FgoConfig) -> None:
        self.cfg = cfg
        self._smoothers: dict[int, SmootherCluster] = {}

    def run(self, tasks: Sequence[SmootherTask]) -> list[ClusterResult | Exception]:
        """Each task's result, or the exception it raised (its smoother is then forgotten)."""
        return [self.run_one(t) for t in tasks]

    def run_one(self, task: SmootherTask) -> ClusterResult | Exception:
        if task.create:
            self._smoothers[task.slot] = SmootherCluster(self.cfg, task.vehicles)
        sm = self._smoothers[task.slot]
        try:
            return sm.update(
                task.blocks,
                task.ranges,
                task.priors,
                task.initial,
                task.timestamps,
                task.cov_keys,
                task.oldest_step,
                task.estimate_keys,
                converge=task.converge,
            )
        except Exception as exc:  # GTSAM raises RuntimeError subclasses; the caller decides
            del self._smoothers[task.slot]  # its state is unknown after a failed update
            return exc

    def status(self) -> tuple[int, int]:
        """(processes, how many of them died): this one alone."""
        return 1, 0

    def keep(self, slots: set[int]) -> None:
        """Forget the smoothers of every other slot."""
        for s in [s for s in self._smoothers if s not in slots]:
            del self._smoothers[s]

    def close(self) -> None:
        self._smoothers.clear()
