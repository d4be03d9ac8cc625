"""A real recording made harder on purpose: stretches where the receiver tracks only a few satellites.

The simulator's canyons cannot show how the estimators behave on a real receiver's clock and
multipath when the sky closes: its clocks are far steadier than a real TCXO (docs/fgo.md, "Few
satellites on a real receiver"). So a real static recording is thinned instead. Outside the
stretches every epoch keeps the systems asked for. Inside one, the satellites are ranked in an
order drawn from `seed` and the stretch's index, and each epoch keeps the first `keep` of them it
tracks: which few a street leaves open is an accident of its buildings, and whether their
geometry is good or poor is what the seeds vary. The antenna stands still, which the estimators
are not told (kinematic processing), so every metre of drift in a stretch is the estimator's.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from coplane.recording.model import ObsEpoch
from coplane.recording.reader import Recording


@dataclass(frozen=True)
class Stretch:
    """Seconds after the receiver's first epoch: from `start_s`, for `length_s`."""

    start_s: float
    length_s: float

    def __post_init__(self) -> None:
        if not (np.isfinite(self.start_s) and np.isfinite(self.length_s) and self.length_s > 0.0):
            raise ValueError(f"a stretch needs a finite start and a positive length, got {self}")

    def covers(self, dt_s: float) -> bool:
        return self.start_s <= dt_s < self.start_s + self.length_s


# Three stretches of growing length: short canyon, long canyon, a city block with three satellites.
DEFAULT_STRETCHES = (Stretch(100.0, 20.0), Stretch(300.0, 45.0), Stretch(600.0, 90.0))
# the stretches of the 205-epoch Kowloon Tong drive (bench/few_satellites_real.py, the tests)
CAR_STRETCHES = (Stretch(30.0, 20.0), Stretch(80.0, 45.0), Stretch(140.0, 60.0))


class FewSatelliteRecording(Recording):
    """`rec` with each receiver's epochs thinned (the base station's are left alone)."""

    def __init__(
        self,
        rec: Recording,
        stretches: Sequence[Stretch] = DEFAULT_STRETCHES,
        keep: int = 3,
        systems: str = "GC",
        seed: int = 1,
    ) -> None:
        super().__init__(rec.manifest, rec.signals)
        if keep < 0:
            raise ValueError(f"keep must be >= 0, got {keep}")
        self.stretches = tuple(stretches)
        self.keep = keep
        self.systems = systems
        self.seed = seed
        self._thinned: dict[str, list[ObsEpoch]] = {}

    def vehicle_epochs(self, vid: str) -> list[ObsEpoch]:
        if vid not in self._thinned:
            epochs = super().vehicle_epochs(vid)
            t0 = epochs[0].time.seconds if epochs else 0.0
            sats = sorted({s.sat for e in epochs for s in e.sats})
            rankings = [self._ranking(k, sats) for k in range(len(self.stretches))]
            self._thinned[vid] = [self._thin(e, e.time.seconds - t0, rankings) for e in epochs]
        return self._thinned[vid]

    def stretch_at(self, dt_s: float) -> int | None:
        """The index of the stretch `dt_s` seconds after the first epoch lies in, if any."""
        return next((k for k, s in enumerate(self.stretches) if s.covers(dt_s)), None)

    def in_stretch(self, dt_s: float) -> bool:
        """Whether `dt_s` seconds after the first epoch lies in a thinned stretch."""
        return self.stretch_at(dt_s) is not None

    def _ranking(self, k: int, sats: list[str]) -> dict[str, int]:
        order = np.random.default_rng([self.seed, k]).permutation(len(sats))
        return {sats[i]: rank for rank, i in enumerate(order.tolist())}

    def _thin(self, e: ObsEpoch, dt_s: float, rankings: list[dict[str, int]]) -> ObsEpoch:
        sats = [s for s in e.sats if s.sat[:1] in self.systems]
        k = self.stretch_at(dt_s)
        if k is not None:
            sats = sorted(sats, key=lambda s: rankings[k][s.sat])[: self.keep]
        return replace(e, sats=tuple(sats))
