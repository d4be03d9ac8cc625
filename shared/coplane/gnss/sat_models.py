"""The per-satellite models an SPP fit evaluates (elevation, atmospheric delay, sigma), and the
ones a receiver carries from one fit to the next (`SatModels`), where its next fit starts."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from coplane.gnss.measurements import SatMeasurement
from coplane.gtime import GpsTime
from coplane.typing import AnyArray as Vec

# SatModels older than this do not start a fit (at 30 s a delay has moved by centimetres at most)
MODELS_MAX_AGE_S = 30.0


@dataclass
class FitAtmosphere:
    """A fit's satellites as modelled at position `at`: elevation, delay and sigma (`at` None:
    evaluated nowhere yet, or `carried` over from the receiver's previous fit)."""

    at: Vec | None
    el: Vec
    delay: Vec  # TGD + iono + tropo (0 with DGNSS), m
    sig: Vec
    carried: bool = False  # the previous epoch's models (SatModels), evaluated nowhere near here

    def without(self, i: int) -> FitAtmosphere:
        """The same without satellite `i` (excluded by RAIM: the re-solve starts from the rest)."""
        keep = np.arange(len(self.el)) != i
        return FitAtmosphere(self.at, self.el[keep], self.delay[keep], self.sig[keep], self.carried)


@dataclass(frozen=True)
class SatModels:
    """Satellites as modelled where the receiver's fits ended: elevation (rad), atmospheric delay
    (iono + tropo, m, without the TGD, which goes with the ephemeris), sigma (m), and the epoch
    (GPS seconds) each was modelled at.

    The receiver's next epoch starts its iterations from these instead of evaluating the models
    at its previous fix: a second later the satellites have moved by 1e-4 rad, which changes a
    delay by millimetres, and the models are evaluated where that fit converges in any case
    (`spp.solve_spp`), so the result is the same while each epoch saves one evaluation of them.
    `merged` keeps a satellite that was out of sight for a few epochs (in a street, the set
    changes almost every epoch), up to `MODELS_MAX_AGE_S`.
    """

    time: GpsTime  # the latest fit's epoch
    differential: bool
    by_sat: dict[str, tuple[float, float, float, float]]

    def atmosphere(
        self, t: GpsTime, sats: Sequence[SatMeasurement], tgd: Vec, differential: bool
    ) -> FitAtmosphere | None:
        """A starting atmosphere for `sats` at `t`; None when any of them is missing or older than
        `MODELS_MAX_AGE_S`, or when the mode (standalone or DGNSS) differs."""
        if differential != self.differential:
            return None
        now = t.seconds
        try:
            rows = [self.by_sat[m.sat] for m in sats]
        except KeyError:
            return None
        if not all(0.0 < now - r[3] <= MODELS_MAX_AGE_S for r in rows):
            return None
        el, delay, sig, _ = (np.array(c) for c in zip(*rows, strict=True))
        return FitAtmosphere(None, el, tgd + delay, sig, carried=True)

    def merged(self, older: SatModels | None) -> SatModels:
        """These models over `older`'s satellites that are not here and not too old."""
        if older is None or older.differential != self.differential:
            return self
        now = self.time.seconds
        kept = {
            k: r for k, r in older.by_sat.items() if k not in self.by_sat and now - r[3] <= MODELS_MAX_AGE_S
        }
        return replace(self, by_sat={**kept, **self.by_sat}) if kept else self
