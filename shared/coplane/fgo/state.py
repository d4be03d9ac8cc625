"""What the factor-graph estimator keeps between epochs, in one object the stages share.

Preparation reads the window and the current estimate (for initial values and links), block
building registers keys, and cluster solving writes estimates and covariances back. Keeping that
state in one place lets each stage live in its own module (`prepare`, `blocks`, `solve`) without
reaching into the `FusionEstimator`.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import gtsam
import numpy as np

from coplane.fgo.keys import KeyRegistry
from coplane.fgo.window import Window
from coplane.gtime import GpsTime
from coplane.typing import Mat, Vec


@dataclass
class GraphState:
    """The window of state blocks, the current estimate of each state and its reported covariance."""

    window: Window
    keys: KeyRegistry = field(default_factory=KeyRegistry)
    # Current estimate of every state in the window, kept as one gtsam.Values: a cluster's initial
    # values are one extract() and its result one update(), not a loop over keys.
    values: gtsam.Values = field(default_factory=gtsam.Values)
    # Covariance of each state as reported when it was the newest: the source of the anchor.
    cov: dict[int, Mat] = field(default_factory=dict)
    step: int = 0  # index of the epoch being solved
    # step at which each vehicle's current track started (its state came from its SPP)
    track_start: dict[str, int] = field(default_factory=dict)
    # with FgoConfig.clock_drift_carry, each vehicle's last Doppler clock drift (m/s) and its epoch:
    # the clock's step through epochs without one (`links.clock_drift`); it outlives the window
    drift_seen: dict[str, tuple[float, GpsTime]] = field(default_factory=dict)
    # the vehicles whose receiver reports no Doppler, as their latest epoch with satellites said
    # (`VehicleEpochInput.doppler_observed`): their motion link is `FgoConfig.no_doppler_velocity`
    no_doppler: set[str] = field(default_factory=set)

    def position(self, key: int) -> Vec:
        return np.array(self.values.atPoint3(key), dtype=float)

    def clock(self, key: int) -> float:
        return float(self.values.atDouble(key))


@dataclass
class StepStats:
    """What one epoch's solve reports besides the estimates."""

    iterations: int = 0
    error_before: float = 0.0
    error_after: float = 0.0
    anchors: int = 0
    rejected: Counter[str] = field(default_factory=Counter)
    skipped: dict[str, str] = field(default_factory=dict)

    def reject(self, kind: str, n: int = 1) -> None:
        self.rejected[kind] += n
