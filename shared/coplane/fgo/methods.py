"""The paper's methods as named configurations of the one estimator, and ranging interruption.

A method is the estimator's `FgoConfig` plus what the per-vehicle step must do about planes
(`planes`: none / fitted from the whole fleet's solved positions / from the vehicle's own solved
positions only, and whether the plane availability detection + RANSAC fault exclusion runs).

Ranging interruption (paper Sec. 5.3, "randomly remove 20 %, 40 %, ... of inter-node ranging
measurements between each pair"): decided per (pair, epoch index) from (seed, pair) alone, so an
offline run and a streaming server drop exactly the same ranges. Epoch indices are cut into blocks
of `block` epochs; each (pair, block) gets a seeded random permutation of its epochs and the first
round(rate * block) of them are dropped. So per pair the removed share is exactly `rate` over every
full block (of epochs where the pair had a range at all: close to `rate`), at random epochs.
"""

from __future__ import annotations

import dataclasses
import functools
import zlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from coplane.baselines import DdCpEkf, GampCp, NonCpEkf, gamp_config
from coplane.fgo.config import FgoConfig, Solver
from coplane.fgo.inputs import Estimator, RangeObs

PlaneSource = Literal["none", "fleet", "self"]
INTERRUPTION_BLOCK = 100


@dataclass(frozen=True)
class MethodSpec:
    name: str
    fgo: FgoConfig
    planes: PlaneSource  # where the per-vehicle step takes the points for its road plane
    plane_fault_exclusion: bool  # plane availability detection + RANSAC FE (paper Sec. 3.2)
    description: str
    # Estimators that are not this factor graph (EKF, DD-CP, GAMP baselines) plug in here; they
    # take the same EpochInput and return the same FleetSolution (fgo.inputs.Estimator).
    estimator_factory: Callable[[MethodSpec], Estimator] | None = None

    def build_estimator(self) -> Estimator:
        """A fresh estimator for this method (the factor graph unless a factory is given)."""
        if self.estimator_factory is not None:
            return self.estimator_factory(self)
        from coplane.fgo.engine import FusionEstimator

        return FusionEstimator(self.fgo)

    def with_solver(self, solver: Solver | None = None, window_epochs: int | None = None) -> MethodSpec:
        """The same method on another solver and/or window length."""
        changes: dict[str, object] = {}
        if solver is not None:
            changes["solver"] = solver
        if window_epochs is not None:
            changes["window_epochs"] = window_epochs
        return dataclasses.replace(self, fgo=dataclasses.replace(self.fgo, **changes))  # type: ignore[arg-type]


def _cfg(ranging: bool, planes: bool) -> FgoConfig:
    # Huber on pseudoranges and ranges for every method alike: our stand-in for the paper's
    # cooperative integrity monitoring (ref. [28]), which removed NLOS/multipath faults before the
    # FGO. Without it, NLOS biases dominate all methods on urban data (docs/results.md compares).
    return FgoConfig(use_ranging=ranging, use_planes=planes, use_velocity=True, robust="huber")


METHODS: dict[str, MethodSpec] = {
    m.name: m
    for m in (
        MethodSpec(
            "non-cp",
            _cfg(ranging=False, planes=False),
            "none",
            False,
            "Each vehicle alone: pseudorange + Doppler velocity factors in the sliding window.",
        ),
        MethodSpec(
            "mci",
            _cfg(ranging=True, planes=False),
            "none",
            False,
            "Multi-agent collaborative integration: GNSS + inter-vehicle (UWB) ranging factors.",
        ),
        MethodSpec(
            "pc",
            _cfg(ranging=True, planes=True),
            "fleet",
            True,
            "Proposed: plane constraints fitted from the fleet's solved positions (with detection"
            " and fault exclusion) + ranging.",
        ),
        MethodSpec(
            "pc-no-ir",
            _cfg(ranging=False, planes=True),
            "fleet",
            True,
            "Proposed without inter-vehicle ranging (range-free CP through the fleet's planes).",
        ),
        MethodSpec(
            "pc-no-ir-no-fe",
            _cfg(ranging=False, planes=True),
            "fleet",
            False,
            "As pc-no-ir but planes are used without availability detection / fault exclusion.",
        ),
        MethodSpec(
            "pc-self",
            _cfg(ranging=False, planes=True),
            "self",
            True,
            "A vehicle alone, constrained by a plane fitted from its own solved history (no fleet).",
        ),
        # Table I comparison methods that are not this factor graph (docs/methods.md)
        MethodSpec(
            "non-cp-ekf",
            _cfg(ranging=False, planes=False),
            "none",
            False,
            "Non-CP baseline: per-vehicle EKF with pseudorange + Doppler updates and innovation gating.",
            estimator_factory=lambda spec: NonCpEkf(),
        ),
        MethodSpec(
            "dd-cp",
            _cfg(ranging=False, planes=False),
            "none",
            False,
            "GNSS-based CP: centralised EKF with absolute and inter-vehicle double-differenced pseudoranges.",
            estimator_factory=lambda spec: DdCpEkf(),
        ),
        MethodSpec(
            "gamp-cp",
            _cfg(ranging=True, planes=False),
            "none",
            False,
            "GAMP CP: damped GAMP over pseudoranges + UWB ranges; priors from each vehicle's EKF prediction.",
            estimator_factory=lambda spec: GampCp(gamp_config(spec.fgo)),
        ),
    )
}


def get_method(name: str, *, solver: Solver | None = None, window_epochs: int | None = None) -> MethodSpec:
    """The named method, optionally on another solver / window length."""
    try:
        spec = METHODS[name]
    except KeyError:
        raise ValueError(f"unknown method {name!r}; valid methods: {', '.join(METHODS)}") from None
    return spec.with_solver(solver, window_epochs) if (solver or window_epochs) else spec


# ----------------------------------------------------------------------------------------------
# ranging interruption (paper Sec. 5.3)


def _check_rate(rate: float) -> float:
    r = float(rate)
    if not 0.0 <= r <= 1.0:
        raise ValueError(f"interruption rate must be in [0, 1], got {rate!r}")
    return r


@functools.lru_cache(maxsize=4096)
def _block_ranks(seed: int, a: str, b: str, block_index: int, block: int) -> np.ndarray:
    """Rank of each epoch of one (pair, block) in a seeded random permutation."""
    rng = np.random.default_rng(
        [seed & 0xFFFFFFFF, zlib.crc32(a.encode()), zlib.crc32(b.encode()), block_index]
    )
    ranks = np.empty(block, dtype=np.int64)
    ranks[rng.permutation(block)] = np.arange(block)
    ranks.setflags(write=False)
    return ranks


def interrupt_range(
    pair: tuple[str, str], epoch_index: int, rate: float, seed: int = 0, *, block: int = INTERRUPTION_BLOCK
) -> bool:
    """True when the range of `pair` at `epoch_index` is removed (order of the pair irrelevant)."""
    r = _check_rate(rate)
    if r <= 0.0:
        return False
    if r >= 1.0:
        return True
    if epoch_index < 0:
        raise ValueError(f"epoch index must be >= 0, got {epoch_index}")
    a, b = sorted(pair)
    bi, pos = divmod(int(epoch_index), block)
    return bool(_block_ranks(int(seed), a, b, bi, block)[pos] < round(r * block))


def interrupt_ranges(
    ranges_by_epoch: Sequence[Sequence[RangeObs]],
    rate: float,
    rng_seed: int = 0,
    *,
    block: int = INTERRUPTION_BLOCK,
) -> list[tuple[RangeObs, ...]]:
    """Per-epoch range lists (index = epoch index) with the interrupted ones removed.

    The same decisions as `interrupt_range`, so offline and streaming runs agree.
    """
    _check_rate(rate)
    return [
        tuple(r for r in ranges if not interrupt_range((r.a, r.b), k, rate, rng_seed, block=block))
        for k, ranges in enumerate(ranges_by_epoch)
    ]
