"""Graduated non-convexity on the LM window (`FgoConfig.gnc`; tried and not adopted, docs/fgo.md).

GTSAM's `GncLMOptimizer` (truncated least squares or Geman-McClure) instead of LM: each epoch's
pseudoranges, planes and the ranges are the candidates, every link, anchor and prior a known inlier.
"""

from __future__ import annotations

from collections.abc import Sequence

import gtsam
import numpy as np

from coplane.fgo import factors as F
from coplane.fgo.config import FgoConfig
from coplane.fgo.keys import BIAS_CHR, POSITION_CHR
from coplane.fgo.recipes import Recipe
from coplane.fgo.window import (
    ClusterResult,
    RangeEdge,
    StateBlock,
    build_graph,
    lm_params,
    marginal_covariances,
)
from coplane.gnss.constants import C

LOOSE_CLOCK_S = 1e-5  # GNC's prior on every clock (3 km): keeps a system without inliers solvable


def gnc_candidates(
    blocks: Sequence[StateBlock], ranges: Sequence[RangeEdge], n_priors: int, oldest_step: int
) -> list[int]:
    """Indices, in `build_graph`'s order, of the factors GNC may reject: each block's
    pseudoranges and plane (its graph's first factors, `blocks.build_block`) and the ranges."""
    out: list[int] = []
    i = n_priors
    for b in blocks:
        n = b.counts.get("pseudorange", 0) + b.counts.get("plane", 0)
        out.extend(range(i, i + n))
        i += int(b.graph().size())
        i += sum(len(ln.factors()) for ln in b.links if ln.prev_step >= oldest_step)
    out.extend(range(i, i + len(ranges)))
    return out


def solve_gnc_window(
    cfg: FgoConfig,
    blocks: Sequence[StateBlock],
    ranges: Sequence[RangeEdge],
    priors: Sequence[Recipe],
    initial: gtsam.Values,
    cov_keys: Sequence[int],
    oldest_step: int,
) -> ClusterResult:
    """`solve_lm_window` with GTSAM's graduated non-convexity instead of LM; the marginals of the
    inliers' graph."""
    graph = build_graph(blocks, ranges, priors, oldest_step)
    cand = set(gnc_candidates(blocks, ranges, sum(len(p.factors()) for p in priors), oldest_step))
    params = gtsam.GncLMParams(lm_params(cfg))
    params.setLossType(gtsam.GncLossType.TLS if cfg.gnc == "tls" else gtsam.GncLossType.GM)
    # TLS may reject every pseudorange of one system at an epoch: a loose prior (1e-5 s, 3 km) on
    # each clock (and each system's offset from the receiver clock, in metres) keeps that variable
    # determined instead of making the system singular
    for key in initial.keys():  # noqa: SIM118 (gtsam.Values is not iterable)
        kind = chr(gtsam.Symbol(key).chr())
        if kind != POSITION_CHR:
            sigma = LOOSE_CLOCK_S * C if kind in BIAS_CHR.values() else LOOSE_CLOCK_S
            graph.add(F.clock_prior(key, initial.atDouble(key), sigma))
    params.setKnownInliers([i for i in range(int(graph.size())) if i not in cand])
    opt = gtsam.GncLMOptimizer(graph, initial, params)
    opt.setInlierCostThresholdsAtProbability(cfg.gnc_inlier_probability)
    before = graph.error(initial)
    values = opt.optimize()
    weights = np.asarray(opt.getWeights(), dtype=float)
    inliers = gtsam.NonlinearFactorGraph()
    for i in range(int(graph.size())):
        if i not in cand or weights[i] >= 0.5:
            inliers.add(graph.at(i))
    after = inliers.error(values)
    if not np.isfinite(after):
        raise RuntimeError(f"GNC returned a non-finite error {after}")
    covs = marginal_covariances(gtsam.Marginals(inliers, values), cov_keys) if cov_keys else {}
    return ClusterResult(values, covs, 0, float(before), float(after))
