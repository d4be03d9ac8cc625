"""The epoch skeleton the baselines share: order check, validation, accounting, the solution.

Every baseline does the same around its own filter update: refuse an epoch that is not after
the previous one, validate the untrusted input once (`coplane.estimation.validate_epoch`), count
what was rejected or skipped, and assemble the `FleetSolution`. Subclasses implement `solve` only.
"""

from __future__ import annotations

import time
from abc import ABC, abstractmethod
from collections import Counter
from dataclasses import dataclass, field

from coplane.estimation.contract import EpochInput, FleetSolution, VehicleEstimate
from coplane.estimation.validate import ValidEpoch, out_of_order_reason, skipped_epoch, validate_epoch
from coplane.gtime import GpsTime


@dataclass
class EpochOutcome:
    """What one epoch's `solve` produces, filled in place."""

    estimates: dict[str, VehicleEstimate] = field(default_factory=dict)
    counts: Counter[str] = field(default_factory=Counter)  # measurements used, by kind
    rejected: Counter[str] = field(default_factory=Counter)  # measurements dropped, by kind
    skipped: dict[str, str] = field(default_factory=dict)  # vehicle -> reason
    n_clusters: int = 0


class BaselineEstimator(ABC):
    """An `Estimator` whose subclasses only say how a validated epoch updates their filters."""

    uses_ranges: bool = False  # validate (and count) the epoch's inter-vehicle ranges

    def __init__(self) -> None:
        self._last: GpsTime | None = None

    def step(self, epoch: EpochInput) -> FleetSolution:
        """One fleet epoch in time order; never raises on data."""
        t0 = time.perf_counter()
        reason = out_of_order_reason(epoch, self._last)
        if reason is not None:
            return skipped_epoch(epoch, self._last, reason, time.perf_counter() - t0)
        self._last = epoch.time
        valid = validate_epoch(epoch, planes=False, ranges=self.uses_ranges)
        out = EpochOutcome(rejected=Counter(valid.rejected), skipped=dict(valid.skipped))
        self.solve(valid, out)
        return FleetSolution(
            time=valid.time,
            estimates=out.estimates,
            solve_time_s=time.perf_counter() - t0,
            factor_counts={k: n for k, n in sorted(out.counts.items()) if n},
            skipped=out.skipped,
            rejected={k: n for k, n in sorted(out.rejected.items()) if n},
            n_clusters=out.n_clusters,
        )

    @abstractmethod
    def solve(self, valid: ValidEpoch, out: EpochOutcome) -> None:
        """Update the filters with one validated epoch and fill `out`."""
