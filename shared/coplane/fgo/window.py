"""The sliding window (per-epoch factor blocks) and the three ways to solve a cluster of it.

The window keeps, per epoch, each vehicle's `StateBlock` (its keys, initial values and its own
factors, made once, as `Recipe`s) and the epoch's range factors; nothing is remade later, so the
per-epoch Python cost is proportional to what is new, not to the window.

Solvers, one instance per cluster of vehicles (connected by ranges within the window):
  - `solve_lm_window`: the paper's scheme, stateless: graph = the window's blocks + ranges +
    anchor priors, Levenberg-Marquardt, gtsam.Marginals for the covariances.
  - `coplane.fgo.smoother.SmootherCluster`: a gtsam.IncrementalFixedLagSmoother (iSAM2) or
    gtsam.BatchFixedLagSmoother with lag window_epochs - 1, fed only the new epoch's factors;
    states leaving the window are marginalised by GTSAM. Created ("rebuilt") from the whole window
    + anchors when the cluster is new, merges or splits.
"""

from __future__ import annotations

from collections import Counter, deque
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol, TypeVar

import gtsam
import numpy as np
from numpy.typing import NDArray

from coplane.components import UnionFind
from coplane.fgo.config import FgoConfig
from coplane.fgo.recipes import Recipe, realise
from coplane.gtime import GpsTime
from coplane.typing import Mat, Vec


class _Range(Protocol):
    """What `Window.bounded` reads of a range (the estimator's validated ranges)."""

    @property
    def a(self) -> str: ...
    @property
    def b(self) -> str: ...
    @property
    def range_m(self) -> float: ...


R = TypeVar("R", bound=_Range)


class Link(Recipe):
    """A factor from an earlier state of the vehicle (velocity / motion / clock step).

    Kept apart from the block's own factors because it dies with the earlier state: when that
    state leaves the window, the paper deletes "the old states and their associated factors".
    """

    __slots__ = ("kind", "prev_step")

    def __init__(self, prev_step: int, kind: str, build: Callable[..., Any], *args: Any) -> None:
        super().__init__(build, *args)
        self.prev_step = prev_step
        self.kind = kind


@dataclass
class StateBlock:
    """One vehicle at one epoch: its variables, its own factors and its links to earlier states."""

    vehicle_id: str
    step: int
    time: GpsTime
    pos_key: int
    clock_keys: dict[str, int]  # GNSS system -> key, systems sorted
    init_pos: Vec
    init_clocks: dict[int, float]  # clock key -> seconds (an offset's key -> metres)
    recipes: list[Recipe]  # factors on this epoch's variables only
    counts: dict[str, int]  # of the factors of `recipes`, by kind
    links: list[Link]
    n_pseudoranges: int
    plane_used: bool
    velocity: Vec | None  # Doppler velocity at this epoch (for the next epoch's displacement)
    clock_drift_mps: float | None
    has_fix: bool
    # FgoConfig.clock_isb_sigma_m: the system whose clock is the receiver's one clock (its only
    # key in `clock_keys`, observed at this epoch or not), and each other observed system -> key
    # of its offset from that clock (metres); else None and empty
    clock_ref: str | None = None
    bias_keys: dict[str, int] = field(default_factory=dict)
    common_cov: Mat | None = None  # Prepared.common_cov: added to the reported covariance only
    fde_dropped: bool = False  # Prepared.fde_dropped: its pseudoranges all dropped, by rule
    excluded: tuple[str, ...] = ()  # Prepared.excluded: reported with the estimate
    _graph: gtsam.NonlinearFactorGraph | None = field(default=None, repr=False, compare=False)

    @property
    def keys(self) -> list[int]:
        return [self.pos_key, *self.clock_keys.values(), *self.bias_keys.values()]

    def settle(self) -> None:
        """Build the block's factors and links now and keep only them (`Recipe.settle`)."""
        self.graph()
        self.recipes = []
        for ln in self.links:
            ln.settle()

    def graph(self) -> gtsam.NonlinearFactorGraph:
        """The factors of `recipes`, built once: a window graph takes them in one call."""
        if self._graph is None:
            self._graph = realise(self.recipes)
        return self._graph


class RangeEdge(Recipe):
    """A factor between two vehicles' states of one epoch: a range, or a height link beside one
    (`kind`, what the factor counts expose)."""

    __slots__ = ("a", "b", "key_a", "key_b", "kind")

    def __init__(
        self, a: str, b: str, key_a: int, key_b: int, kind: str, build: Callable[..., Any], *args: Any
    ) -> None:
        super().__init__(build, *args)
        self.a, self.b, self.key_a, self.key_b, self.kind = a, b, key_a, key_b, kind


def edge_counts(edges: Iterable[RangeEdge]) -> dict[str, int]:
    """How many edges of each kind."""
    return dict(Counter(e.kind for e in edges))


@dataclass
class StepRecord:
    step: int
    time: GpsTime
    blocks: dict[str, StateBlock]
    ranges: list[RangeEdge]


class Window:
    """The last `window_epochs` epochs: blocks per step and per vehicle, and factor totals."""

    def __init__(self, window_epochs: int) -> None:
        self.window_epochs = window_epochs
        self.steps: deque[StepRecord] = deque()
        self.by_vehicle: dict[str, deque[StateBlock]] = {}
        self.counts: dict[str, int] = {}  # factors in the window by kind (links to live states)
        self._links_by_prev: dict[int, dict[str, int]] = {}

    def _count(self, counts: dict[str, int], sign: int) -> None:
        for k, n in counts.items():
            self.counts[k] = self.counts.get(k, 0) + sign * n

    def _count_links(self, blk: StateBlock, sign: int) -> None:
        for ln in blk.links:
            self.counts[ln.kind] = self.counts.get(ln.kind, 0) + sign
            by = self._links_by_prev.setdefault(ln.prev_step, {})
            by[ln.kind] = by.get(ln.kind, 0) + sign

    @property
    def oldest_step(self) -> int | None:
        return self.steps[0].step if self.steps else None

    def prune(self, oldest_step: int) -> list[StateBlock]:
        """Delete steps older than `oldest_step`; returns the removed blocks."""
        removed: list[StateBlock] = []
        while self.steps and self.steps[0].step < oldest_step:
            rec = self.steps.popleft()
            for vid in sorted(rec.blocks):
                blk = rec.blocks[vid]
                dq = self.by_vehicle[vid]
                assert dq[0] is blk
                dq.popleft()
                if not dq:
                    del self.by_vehicle[vid]
                self._count(blk.counts, -1)
                removed.append(blk)
            self._count(edge_counts(rec.ranges), -1)
            self._count(self._links_by_prev.pop(rec.step, {}), -1)  # links into the deleted states
        return removed

    def push(self, rec: StepRecord) -> None:
        self.steps.append(rec)
        for vid in sorted(rec.blocks):
            blk = rec.blocks[vid]
            self.by_vehicle.setdefault(vid, deque()).append(blk)
            self._count(blk.counts, +1)
            self._count_links(blk, +1)
        self._count(edge_counts(rec.ranges), +1)

    def drop_new(self, vehicles: Iterable[str]) -> None:
        """Remove the newest step's blocks (and their ranges) of `vehicles` after a failed solve."""
        rec = self.steps[-1]
        gone = set(vehicles)
        for vid in sorted(gone):
            blk = rec.blocks.pop(vid, None)
            if blk is None:
                continue
            dq = self.by_vehicle[vid]
            assert dq[-1] is blk
            dq.pop()
            if not dq:
                del self.by_vehicle[vid]
            self._count(blk.counts, -1)
            self._count_links(blk, -1)
        self._count(edge_counts(r for r in rec.ranges if r.a in gone or r.b in gone), -1)
        rec.ranges = [r for r in rec.ranges if r.a not in gone and r.b not in gone]

    def vehicles(self) -> list[str]:
        return sorted(self.by_vehicle)

    def bounded(self, ranges: Sequence[R], new: Iterable[str], cap: int) -> list[R]:
        """`ranges` (a new epoch's, of vehicles in the window or `new`) without those that would
        join two of the window's clusters into one of more than `cap` vehicles.

        Shortest first, ties by pair, as Kruskal's algorithm (the same choice as
        `steps.fusion.bounded_ranges` for one epoch); a range inside a cluster is always kept. The
        window's clusters only shrink as steps leave it, so none ever exceeds `cap`. Kept ranges
        come back in their given order, so a fleet within the bound gets the same graph."""
        if cap <= 0 or not ranges:
            return list(ranges)
        uf = UnionFind(sorted(set(self.by_vehicle).union(new)))
        for rec in self.steps:
            for e in rec.ranges:
                uf.union(e.a, e.b)
        order = sorted(range(len(ranges)), key=lambda i: (ranges[i].range_m, ranges[i].a, ranges[i].b))
        dropped: set[int] = set()
        for i in order:  # in order: each kept range joins the sets the next ones are checked against
            if not uf.union_within(ranges[i].a, ranges[i].b, cap):
                dropped.add(i)
        return [r for i, r in enumerate(ranges) if i not in dropped]

    def partition(self, split: bool) -> list[ClusterView]:
        """Connected components of vehicles linked by ranges in the window, with their content.

        One pass over the window; clusters sorted by their smallest vehicle id, blocks in step then
        vehicle order, so the same inputs always give the same graphs. `split=False`: one cluster.
        """
        vids = sorted(self.by_vehicle)
        if not vids:
            return []
        uf = UnionFind(vids)
        if split:
            for rec in self.steps:
                for r in rec.ranges:
                    uf.union(r.a, r.b)
        else:
            for v in vids[1:]:
                uf.union(vids[0], v)
        find = uf.find
        views: dict[str, ClusterView] = {}
        for v in vids:
            root = find(v)
            views.setdefault(root, ClusterView([], [], [])).vehicles.append(v)
        for rec in self.steps:
            for vid in sorted(rec.blocks):
                views[find(vid)].blocks.append(rec.blocks[vid])
            for r in rec.ranges:
                views[find(r.a)].ranges.append(r)
        return [views[root] for root in sorted(views)]


@dataclass
class ClusterView:
    """The part of the window that one cluster solves: its vehicles, blocks and ranges."""

    vehicles: list[str]
    blocks: list[StateBlock]
    ranges: list[RangeEdge]


@dataclass
class ClusterResult:
    values: gtsam.Values
    covariances: dict[int, NDArray[np.float64]] = field(default_factory=dict)
    iterations: int = 0
    error_before: float = float("nan")
    error_after: float = float("nan")


def lm_params(cfg: FgoConfig) -> gtsam.LevenbergMarquardtParams:
    p = gtsam.LevenbergMarquardtParams()
    p.setMaxIterations(cfg.lm_max_iterations)
    p.setRelativeErrorTol(cfg.lm_relative_error_tol)
    p.setAbsoluteErrorTol(cfg.lm_absolute_error_tol)
    return p


def graph_recipes(
    blocks: Sequence[StateBlock],
    ranges: Sequence[RangeEdge],
    extra: Sequence[Recipe],
    oldest_step: int,
) -> list[Recipe]:
    """Priors + blocks (own factors, links to states still in the window) + ranges, in the
    order of the graph's factors."""
    out = list(extra)
    for b in blocks:
        out.extend(b.recipes)
        out.extend(ln for ln in b.links if ln.prev_step >= oldest_step)
    out.extend(ranges)
    return out


def build_graph(
    blocks: Sequence[StateBlock],
    ranges: Sequence[RangeEdge],
    extra: Sequence[Recipe],
    oldest_step: int,
) -> gtsam.NonlinearFactorGraph:
    """The graph of `graph_recipes`, with each block's own factors added in one call."""
    g = realise(extra)
    for b in blocks:
        g.push_back(b.graph())
        for ln in b.links:
            if ln.prev_step >= oldest_step:
                g.add(ln.factor())
    for r in ranges:
        g.add(r.factor())
    return g


def marginal_covariances(
    marginals: gtsam.Marginals | gtsam.ISAM2, keys: Sequence[int]
) -> dict[int, NDArray[np.float64]]:
    """3x3 marginals of `keys`, from one joint query (several times cheaper than one per key)."""
    joint = marginals.jointMarginalCovariance(list(keys))
    return {k: np.array(joint.at(k, k), dtype=float) for k in keys}


def solve_lm_window(
    cfg: FgoConfig,
    blocks: Sequence[StateBlock],
    ranges: Sequence[RangeEdge],
    priors: Sequence[Recipe],
    initial: gtsam.Values,
    cov_keys: Sequence[int],
    oldest_step: int,
) -> ClusterResult:
    """The paper's window: one LM solve over the cluster's window graph, then its marginals."""
    graph = build_graph(blocks, ranges, priors, oldest_step)
    opt = gtsam.LevenbergMarquardtOptimizer(graph, initial, lm_params(cfg))
    before = opt.error()  # the optimizer evaluates the graph at the start and at every step
    values = opt.optimize()
    after = opt.error()
    if not np.isfinite(after):
        raise RuntimeError(f"LM returned a non-finite error {after}")
    covs = marginal_covariances(gtsam.Marginals(graph, values), cov_keys) if cov_keys else {}
    return ClusterResult(values, covs, int(opt.iterations()), float(before), float(after))
