"""The fleet's common residual against the map, which change detection must not mistake for a change.

A pass's residual against its tile carries three errors: the tile's own (which its sigma covers),
the pass's own multipath and NLOS, and what the whole fleet shares at that time. With DGNSS the
last is the base station's code multipath, correlated over minutes, which goes into every
vehicle's corrections (docs/results.md, "One build drive"); without it, the atmosphere's residual.
It moves every pass of a drive the same way, so a per-tile CUSUM sees it on every tile at once,
while a real change (a road re-surfaced, re-graded) moves a few tiles.

So, like a differential correction, the recent passes of every usable tile give a reference, their
median residual (the common offset), and the CUSUM of each tile tests (residual - offset) / sigma.
A change confined to a few tiles (under half of the recent passes) does not move the median.
Written here because it is a median over a sliding window of passes; nothing in numpy or scipy
keeps one.

Not done: rescaling z by the spread the residuals really have (their sigmas claim about twice it,
because the estimator's covariances are inflated to stay honest in deep canyons). On the training
seeds it made every tile's own estimation error, which is the same in each of its passes, add up
in the CUSUM: 51 false changes over the sharpening runs against none (docs/roadmap.md).

While fewer than `change_reference_min_passes` recent passes are at hand (the first seconds of a
drive after a pause, a restarted server: the reference is not stored with the map) a pass is not
tested for a change: its residual could be the new drive's common error, which nothing yet shows.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from coplane.roadmap.config import RoadMapConfig


@dataclass(frozen=True)
class ZReference:
    """What a tile's CUSUM tests: (residual - offset_m) / sigma."""

    offset_m: float = 0.0
    passes: int = 0  # how many recent passes the reference rests on (0: none, z as it is)

    def z(self, residual_m: float, sigma_m: float) -> float:
        """The standardised residual of a pass, corrected for the fleet's common part."""
        return (residual_m - self.offset_m) / sigma_m


NO_REFERENCE = ZReference()  # offset 0: each pass tested on its own z (`change_reference` off)


class CommonResidual:
    """A sliding window of recent passes' (time, residual) across the map's usable tiles."""

    def __init__(self, config: RoadMapConfig) -> None:
        self.config = config
        self._window: deque[tuple[float, float]] = deque(maxlen=config.change_reference_passes)
        # the reference of the current second of evidence time: a fleet closes hundreds of passes
        # per second, and a median a second younger says nothing new about an error that drifts
        # over minutes
        self._cached: tuple[int, ZReference | None] | None = None

    @property
    def latest(self) -> ZReference | None:
        """The newest reference computed (None before the first, or while too few passes were at
        hand): what a server reports, since a large common offset says the fleet's heights and the
        map disagree as a whole (a biased map, or a drive with a biased base station)."""
        return self._cached[1] if self._cached is not None else None

    def add(self, time_s: float, residual_m: float) -> None:
        """One pass's mean residual against a usable tile (non-finite ones are ignored)."""
        if math.isfinite(time_s) and math.isfinite(residual_m):
            self._window.append((time_s, residual_m))

    def reference(self, time_s: float) -> ZReference | None:
        """The reference for a pass at `time_s` from the passes within `change_reference_window_s`
        before it (once per second of evidence time); None while too few are at hand (no change
        test), `NO_REFERENCE` when it is off."""
        cfg = self.config
        if not cfg.change_reference:
            return NO_REFERENCE
        second = math.floor(time_s)
        if self._cached is not None and self._cached[0] == second:
            return self._cached[1]
        rows = [r for t, r in self._window if 0.0 <= time_s - t <= cfg.change_reference_window_s]
        ref = (
            ZReference(float(np.median(rows)), len(rows))
            if len(rows) >= cfg.change_reference_min_passes
            else None
        )
        self._cached = (second, ref)
        return ref
