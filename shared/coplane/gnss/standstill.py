"""Standstill detection from a few Doppler measurements: is the receiver's velocity zero?

Three satellites cannot give a velocity (three components and a clock drift), but they can test
one: with the velocity held at zero only the drift is unknown, and every further Doppler row is
redundant. A road vehicle stands often where the sky is narrow (a red light in a street canyon),
and a standing receiver is where a few-satellite epoch's geometry does the most harm: the window
takes the same biased 3-satellite geometry epoch after epoch as independent information and ran
a static antenna 26-68 m away (docs/fgo.md, "Few satellites on a real receiver"). A detected
standstill lets the fusion hold the vehicle still instead (`FgoConfig.standstill_dead_reckoning`).

A passing residual test alone is no evidence of standing: the rows may be blind to the motion.
So the test also needs power: a horizontal speed of `StandstillOptions.max_detectable_speed_mps`
in the rows' weakest horizontal direction must fail the test with probability `power`. The
vertical speed is not required to be observable: a road vehicle's climb is grade x speed, small
when its horizontal speed is. This is Baarda's minimal detectable bias, applied to the velocity;
neither scipy nor the GNSS packages in use have it for this model, so it is written here.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from coplane.errors import require_finite_positive
from coplane.geo import enu_rotation
from coplane.gnss.lsq import chi2_threshold
from coplane.typing import Vec


@dataclass(frozen=True)
class StandstillOptions:
    """The false-alarm rate and power are textbook values. The detectable speed was chosen on the
    real few-satellite stretches of bench/few_satellites_real.py: the largest that took none of
    the moving car's 3-satellite epochs for a standstill (docs/fgo.md). A car creeping below it
    may be taken as standing, and is then a few metres off after a few seconds."""

    enabled: bool = True
    false_alarm_probability: float = 0.01  # a standing receiver refused: the few-satellite solve runs
    max_detectable_speed_mps: float = 2.0
    power: float = 0.8
    # The test's noise is the receiver's own (`DopplerNoise`): the Doppler sigma model is one for
    # all receivers, and a good one's full-sky residuals are a third of it or less (docs/fgo.md).
    # Its variance factor is learned over about `noise_memory_epochs` full-sky solves, starting
    # from 1 with the weight of `noise_prior_dof` residuals, and kept within the bounds.
    noise_memory_epochs: float = 20.0
    noise_prior_dof: float = 10.0
    noise_factor_bounds: tuple[float, float] = (0.01, 4.0)

    def __post_init__(self) -> None:
        require_finite_positive(
            self,
            (
                "false_alarm_probability",
                "max_detectable_speed_mps",
                "power",
                "noise_memory_epochs",
                "noise_prior_dof",
            ),
            "StandstillOptions.",
        )
        lo, hi = self.noise_factor_bounds
        if not (0.0 < lo <= 1.0 <= hi < math.inf):
            raise ValueError(
                f"StandstillOptions.noise_factor_bounds must hold 1 within (0, inf), got {(lo, hi)!r}"
            )
        if not (self.false_alarm_probability < 1.0 and self.power < 1.0):
            raise ValueError(
                "StandstillOptions.false_alarm_probability and .power must be below 1, "
                f"got {self.false_alarm_probability!r} and {self.power!r}"
            )


@dataclass(frozen=True)
class Standstill:
    """A passed standstill test: the drift with the velocity held at zero (m/s), the residuals of
    the rows (m/s), and the horizontal speed the test would have caught with `power` (m/s)."""

    drift_mps: float
    residuals_mps: Vec
    detectable_speed_mps: float


@dataclass(frozen=True)
class DopplerNoise:
    """A receiver's Doppler variance factor: its full-sky solves' sum of squared normalised
    residuals and their degrees of freedom, both fading by `noise_memory_epochs`."""

    chi2: float = 0.0
    dof: float = 0.0

    def add(self, chi2: float, dof: int, opt: StandstillOptions) -> DopplerNoise:
        """With one more full-sky solve's residuals."""
        if dof < 1 or not math.isfinite(chi2):
            return self
        keep = 1.0 - 1.0 / opt.noise_memory_epochs
        return DopplerNoise(keep * self.chi2 + chi2, keep * self.dof + dof)

    def factor(self, opt: StandstillOptions) -> float:
        """The variance factor of the model's Doppler sigmas for this receiver (1 before any solve)."""
        lo, hi = opt.noise_factor_bounds
        f = (self.chi2 + opt.noise_prior_dof) / (self.dof + opt.noise_prior_dof)
        return min(max(f, lo), hi)


def load_dependencies() -> None:
    """Import what the test's first power computation needs (scipy.optimize, scipy.stats) now.

    For a process that runs the test on its own epochs (an agent, the load generator): its
    first few-satellite standstill must not stall that epoch by the half second of imports.
    Processes that never run it (a fusion server, the API) never call this."""
    import scipy.optimize
    import scipy.stats  # noqa: F401


@functools.lru_cache(maxsize=256)
def noncentrality(false_alarm_probability: float, power: float, dof: int) -> float:
    """The chi-square non-centrality at which the test of `dof` degrees of freedom rejects with
    probability `power` (Baarda's lambda_0)."""
    # imported here (once per argument set: the result is cached), not with the module: a process
    # that never runs the test (a fusion server, the API) is spared half a second and tens of MB
    # at start; one that does loads them when it starts (`load_dependencies`)
    from scipy.optimize import brentq
    from scipy.stats import ncx2

    k = chi2_threshold(false_alarm_probability, dof)
    return float(brentq(lambda lam: ncx2.sf(k, dof, lam) - power, 1e-9, 1e4))


def standstill_test(a: Vec, y: Vec, sigma: Vec, up: Vec, opt: StandstillOptions) -> Standstill | None:
    """Test v = 0 on Doppler rows `a` (n x 4: velocity, drift) with range-rate residuals `y`
    and 1-sigmas `sigma` (already scaled by the receiver's `DopplerNoise`); the rows may include
    a drift pseudo-measurement. None: not standing, or too few rows or too weak a geometry to tell."""
    dof = len(y) - 1
    if dof < 2:  # one redundant row sees the motion along one direction only
        return None
    aw, yw = a / sigma[:, None], y / sigma
    d = aw[:, 3]
    dd = float(d @ d)
    if dd <= 0.0:
        return None
    drift = float(d @ yw) / dd
    r = yw - d * drift
    if float(r @ r) > chi2_threshold(opt.false_alarm_probability, dof):
        return None
    # information on the velocity left after the drift is solved: V' (I - d d'/d'd) V
    v = aw[:, :3]
    vd = v.T @ d
    info = v.T @ v - np.outer(vd, vd) / dd
    # east and north at the geodetic latitude and longitude `up` (an ellipsoid normal) stands for
    h = enu_rotation(math.asin(max(-1.0, min(1.0, float(up[2])))), math.atan2(up[1], up[0]))[:2].T
    weakest = float(np.linalg.eigvalsh(h.T @ info @ h)[0])
    lam = noncentrality(opt.false_alarm_probability, opt.power, dof)
    if not (weakest > 0.0 and math.sqrt(lam / weakest) <= opt.max_detectable_speed_mps):  # NaN: not standing
        return None
    return Standstill(drift, r * sigma, math.sqrt(lam / weakest))
