"""Measurement noise models for pseudorange and Doppler (1-sigma, metres and metres per second).

Default (`WeightingModel`): an additive variance with an elevation part and a C/N0 part,

    sigma^2 = f_sys^2 * ( a^2 + b^2 / sin^2(el) + c^2 * 10^((cn0_ref - cn0) / 10) )

* a^2 + b^2/sin^2(el) is RTKLIB's elevation model (rtkpos.c `varerr`, a = b = err[1..2]*err[0]
  = 0.3 m by default). It stands for multipath and residual atmosphere, which grow towards the
  horizon.
* c^2 * 10^(-(cn0 - cn0_ref)/10) is the thermal-noise term: a delay-lock loop's code jitter
  variance is inversely proportional to the linear C/N0 (Kaplan & Hegarty, DLL jitter; the
  "sigma-epsilon" model of Hartinger & Brunner 1999 and RTKLIB-demo5's SNR term use the same
  10^(-cn0/10) law). Low C/N0 at high elevation (foliage, NLOS in urban canyons) is what the
  elevation term alone misses.
* f_sys scales a whole system (RTKLIB EFACT_*: GPS 1, BDS 1, GLO 1.5, SBAS 3).

Defaults a = b = c = 0.3 m at cn0_ref = 45 dB-Hz give 0.52 m at zenith and 45 dB-Hz, 1.5 m at
15 deg / 35 dB-Hz and 3.5 m at 10 deg / 25 dB-Hz (docs/gnss-models.md compares this with code
residuals of the real data sets). Doppler uses the same shape with 0.05 m/s terms.

`rtklib_variance_m2` reproduces RTKLIB 2.4.3 b34 pntpos `varerr` exactly, for an
RTKLIB-equivalent SPP mode.

Every function takes scalars or equal-length arrays (elevation, C/N0, iono) with one system
letter or a sequence of them: SPP and the node message evaluate a whole epoch in one call.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, overload

import numpy as np
from numpy.typing import ArrayLike, NDArray

Systems = str | Sequence[str]

RTKLIB_DEFAULT_ERR = (100.0, 0.003, 0.003)  # prcopt_default.err[0..2]: factor, a, b
RTKLIB_MIN_EL_RAD = math.radians(5.0)  # pntpos.c MIN_EL: elevations below are clamped
RTKLIB_EFACT = {"G": 1.0, "C": 1.0, "E": 1.0, "J": 1.0, "I": 1.0, "R": 1.5, "S": 3.0}


def _default_system_factor() -> dict[str, float]:
    return dict(RTKLIB_EFACT)


@dataclass(frozen=True)
class WeightingModel:
    """Constants of the elevation + C/N0 noise model (see module docstring for the formula).

    code_*: pseudorange terms (m); doppler_*: range-rate terms (m/s); `cn0_ref_dbhz` is where
    the C/N0 term equals c; a missing (NaN) C/N0 is treated as `cn0_ref_dbhz`. Elevations
    below `min_elevation_rad` are clamped to it, so the model stays finite at the horizon.
    """

    code_a_m: float = 0.3
    code_b_m: float = 0.3
    code_c_m: float = 0.3
    doppler_a_mps: float = 0.05
    doppler_b_mps: float = 0.05
    doppler_c_mps: float = 0.05
    cn0_ref_dbhz: float = 45.0
    min_elevation_rad: float = math.radians(5.0)
    system_factor: dict[str, float] = field(default_factory=_default_system_factor)

    def _variance(self, a: float, b: float, c: float, el: ArrayLike, cn0: ArrayLike, system: Systems) -> Any:
        s = np.sin(np.maximum(el, self.min_elevation_rad))
        cn0 = np.asarray(cn0, dtype=float)
        cn0_eff = np.where(np.isfinite(cn0), cn0, self.cn0_ref_dbhz)
        f = _system_values(self.system_factor, system)
        return f * f * (a * a + b * b / (s * s) + c * c * 10.0 ** ((self.cn0_ref_dbhz - cn0_eff) / 10.0))


def _system_values(table: dict[str, float], system: Systems) -> Any:
    if isinstance(system, str):
        return table.get(system, 1.0)
    return np.array([table.get(s, 1.0) for s in system])


@overload
def _out(x: Any, system: str) -> float: ...
@overload
def _out(x: Any, system: Sequence[str]) -> NDArray[np.float64]: ...
def _out(x: Any, system: Systems) -> float | NDArray[np.float64]:
    """A float for one satellite (callers format and serialise it), an array for several."""
    return float(x) if isinstance(system, str) else np.asarray(x, dtype=float)


DEFAULT_WEIGHTING = WeightingModel()


@overload
def pseudorange_sigma_m(  # type: ignore[overload-overlap]  # str is a Sequence[str]
    el_rad: ArrayLike, cn0_dbhz: ArrayLike, system: str, model: WeightingModel | None = None
) -> float: ...
@overload
def pseudorange_sigma_m(
    el_rad: ArrayLike, cn0_dbhz: ArrayLike, system: Sequence[str], model: WeightingModel | None = None
) -> NDArray[np.float64]: ...
def pseudorange_sigma_m(
    el_rad: ArrayLike, cn0_dbhz: ArrayLike, system: Systems, model: WeightingModel | None = None
) -> float | NDArray[np.float64]:
    """1-sigma pseudorange noise (m); decreases with elevation and with C/N0."""
    m = model or DEFAULT_WEIGHTING
    return _out(np.sqrt(m._variance(m.code_a_m, m.code_b_m, m.code_c_m, el_rad, cn0_dbhz, system)), system)


@overload
def doppler_sigma_mps(  # type: ignore[overload-overlap]  # str is a Sequence[str]
    el_rad: ArrayLike, cn0_dbhz: ArrayLike, system: str, model: WeightingModel | None = None
) -> float: ...
@overload
def doppler_sigma_mps(
    el_rad: ArrayLike, cn0_dbhz: ArrayLike, system: Sequence[str], model: WeightingModel | None = None
) -> NDArray[np.float64]: ...
def doppler_sigma_mps(
    el_rad: ArrayLike, cn0_dbhz: ArrayLike, system: Systems, model: WeightingModel | None = None
) -> float | NDArray[np.float64]:
    """1-sigma range-rate noise (m/s) for a Doppler measurement; same shape as the code model."""
    m = model or DEFAULT_WEIGHTING
    v = m._variance(m.doppler_a_mps, m.doppler_b_mps, m.doppler_c_mps, el_rad, cn0_dbhz, system)
    return _out(np.sqrt(v), system)


_RTKLIB_FACT = {"R": RTKLIB_EFACT["R"], "S": RTKLIB_EFACT["S"]}


@overload
def rtklib_variance_m2(  # type: ignore[overload-overlap]  # str is a Sequence[str]
    el: ArrayLike, system: str, err: tuple[float, float, float] = ..., iono_free: bool = ...
) -> float: ...
@overload
def rtklib_variance_m2(
    el: ArrayLike, system: Sequence[str], err: tuple[float, float, float] = ..., iono_free: bool = ...
) -> NDArray[np.float64]: ...
def rtklib_variance_m2(
    el: ArrayLike,
    system: Systems,
    err: tuple[float, float, float] = RTKLIB_DEFAULT_ERR,
    iono_free: bool = False,
) -> float | NDArray[np.float64]:
    """RTKLIB 2.4.3 b34 pntpos `varerr`: EFACT^2 * err0^2 * (err1^2 + err2^2 / sin(el)).

    Reproduced as written, including its quirks: sin(el) is not squared (rtkpos.c squares it),
    elevation is clamped at 5 deg, and BeiDou uses EFACT_GPS (= EFACT_CMP = 1). With the default
    err this is 0.09 + 0.09/sin(el) m^2. It is only the measurement term: RTKLIB's `rescode`
    adds the ephemeris (URA), code-bias (0.3 m), iono and troposphere variances.
    """
    fact = _system_values(_RTKLIB_FACT, system)
    var = err[0] ** 2 * (err[1] ** 2 + err[2] ** 2 / np.sin(np.maximum(el, RTKLIB_MIN_EL_RAD)))
    if iono_free:
        var = var * 9.0
    return _out(fact * fact * var, system)


# The broadcast Klobuchar model removes only about half of the ionospheric delay (IS-GPS-200
# 20.3.3.5.2.5 states ~50 % rms); RTKLIB uses the same 0.5 factor (ERR_BRDCI). Standalone
# pseudoranges carry that residual on top of the receiver error; DGNSS cancels it.
BROADCAST_IONO_ERROR_FRACTION = 0.5


@overload
def standalone_pseudorange_sigma_m(  # type: ignore[overload-overlap]  # str is a Sequence[str]
    el_rad: ArrayLike, cn0_dbhz: ArrayLike, system: str, iono_m: ArrayLike
) -> float: ...
@overload
def standalone_pseudorange_sigma_m(
    el_rad: ArrayLike, cn0_dbhz: ArrayLike, system: Sequence[str], iono_m: ArrayLike
) -> NDArray[np.float64]: ...
def standalone_pseudorange_sigma_m(
    el_rad: ArrayLike, cn0_dbhz: ArrayLike, system: Systems, iono_m: ArrayLike
) -> float | NDArray[np.float64]:
    """Pseudorange sigma for undifferenced use: receiver error plus the broadcast-iono residual."""
    base = pseudorange_sigma_m(el_rad, cn0_dbhz, system)
    return _out(np.sqrt(base * base + (BROADCAST_IONO_ERROR_FRACTION * np.asarray(iono_m)) ** 2), system)


# The part of a pseudorange's error that stays the same over the fusion window (seconds to
# minutes), which the graph's white-noise model averages down as if it were independent from
# epoch to epoch: the reported covariance adds it back (`FgoConfig.covariance_common_scale`).
# Standalone that is the broadcast models' residual atmosphere, with RTKLIB's budget for it
# (ERR_BRDCI: half the Klobuchar delay; ERR_SAAS: 0.3 m / (sin el + 0.1) for Saastamoinen). DGNSS
# cancels it (0 here): what a base station leaves, its own multipath among others, is in
# `FgoConfig.covariance_scale`, chosen with DGNSS.
SAAS_RESIDUAL_M = 0.3


def common_error_sigma_m(el_rad: ArrayLike, iono_m: ArrayLike, dgnss: ArrayLike) -> NDArray[np.float64]:
    """Per satellite, the 1-sigma (m) of the error common to the window's epochs: the broadcast
    atmosphere's residual, 0 where a DGNSS correction (`dgnss` True) removed the atmosphere."""
    sin_el = np.sin(np.maximum(np.asarray(el_rad, dtype=float), RTKLIB_MIN_EL_RAD))
    residual = np.hypot(
        BROADCAST_IONO_ERROR_FRACTION * np.asarray(iono_m, dtype=float), SAAS_RESIDUAL_M / (sin_el + 0.1)
    )
    return np.where(np.asarray(dgnss, dtype=bool), 0.0, residual)
