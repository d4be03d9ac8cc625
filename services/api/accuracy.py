"""Running accuracy of live solutions against the recording's truth, in bounded memory.

The error of one solution is `coplane.evaluate.metrics.enu_errors` (ENU frame at the truth point,
no alignment), the definition `coplane eval` reports, so the API and the offline evaluation agree
(docs/api.md, `/accuracy`). The statistics cannot be `metrics.accuracy`: it needs every error of
the run, and a live API must stay bounded. So RMSE, mean, bias and max come from exact all-time
sums, and only CEP95 uses a bounded window.
"""

from __future__ import annotations

import bisect
import math
from collections import deque
from collections.abc import Iterable, Mapping

import numpy as np

from coplane.evaluate.metrics import enu_errors
from coplane.gtime import GpsTime
from coplane.typing import Vec

from .models import AccuracyEntry


class TruthTrack:
    """Truth positions of one vehicle keyed by nominal epoch."""

    def __init__(self, points: Mapping[GpsTime, Iterable[float]]) -> None:
        self.points: dict[GpsTime, Vec] = {t: np.asarray(list(p), dtype=float) for t, p in points.items()}
        self.times = sorted(t.seconds for t in self.points)

    def error(self, t: GpsTime, ecef: Iterable[float]) -> tuple[float, float] | None:
        """(horizontal, signed vertical) error at epoch t, or None without truth there."""
        ref = self.points.get(t)
        if ref is None:
            return None
        _, e = enu_errors({t: np.asarray(list(ecef), dtype=float)}, {t: ref})
        # math.hypot, not the np.hypot of metrics.accuracy: the two differ in the last bit for
        # some inputs, and the API has always served math.hypot's value
        return float(math.hypot(e[0, 0], e[0, 1])), float(e[0, 2])

    def count_between(self, first_s: float, last_s: float) -> int:
        """Truth epochs in [first_s, last_s] (GPS seconds, 1 us tolerance): availability's denominator."""
        return bisect.bisect_right(self.times, last_s + 1e-6) - bisect.bisect_left(self.times, first_s - 1e-6)


class RunningAccuracy:
    """H/V errors of one vehicle under one method: exact all-time sums, bounded CEP95 window."""

    def __init__(self, window: int) -> None:
        self.n = 0
        self.sum_h2 = 0.0
        self.sum_v2 = 0.0
        self.sum_h = 0.0
        self.sum_v = 0.0
        self.max_h = 0.0
        self.max_v = 0.0
        self.h: deque[float] = deque(maxlen=window)
        self.last_h: float | None = None

    def add(self, h: float, v: float) -> None:
        self.n += 1
        self.sum_h2 += h * h
        self.sum_v2 += v * v
        self.sum_h += h
        self.sum_v += v
        self.max_h = max(self.max_h, h)
        self.max_v = max(self.max_v, abs(v))
        self.h.append(h)
        self.last_h = h

    def entry(self, vehicle_id: str, method: str, n_truth: int) -> AccuracyEntry:
        """The served entry; statistics are None until a first error (JSON has no NaN)."""
        n = self.n
        ok = n > 0
        return AccuracyEntry(
            vehicle_id=vehicle_id,
            method=method,
            n_truth=n_truth,
            n_solved=n,
            availability=n / n_truth if n_truth else 0.0,
            h_rmse_m=math.sqrt(self.sum_h2 / n) if ok else None,
            v_rmse_m=math.sqrt(self.sum_v2 / n) if ok else None,
            cep95_m=float(np.percentile(np.fromiter(self.h, float), 95)) if self.h else None,
            cep95_samples=len(self.h),
            h_max_m=self.max_h if ok else None,
            v_max_m=self.max_v if ok else None,
            h_mean_m=self.sum_h / n if ok else None,
            v_bias_m=self.sum_v / n if ok else None,
            last_error_h_m=self.last_h,
        )
