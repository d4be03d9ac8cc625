"""Single point positioning: weighted iterative least squares with RAIM fault detection/exclusion.

Model per satellite i (metres):  y_i = P_i - delta_i  =  |p - p_s|_sagnac + b_sys(i) - c*dts_i
                                                          [+ TGD_i + I_i + T_i when not differential]
with one receiver clock per constellation (GPS and BeiDou time differ by an unknown inter-system
bias). `delta_i` is a DGNSS correction (gnss.dgnss) or 0. Fault detection is the global chi-square
test on the weighted residuals; exclusion removes the satellite with the largest standardised
residual (Baarda's w-test) and repeats, so it costs one solve per exclusion rather than RTKLIB's
one solve per candidate. A fix that still fails is returned as "no solution" with the reason,
never as a bad position.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from coplane.geo import ecef_to_geodetic, enu_rotation
from coplane.gnss.atmosphere import GPS_L1_TO_BDS_B1I, iono_delay_m, klobuchar_gps_m, saastamoinen_m
from coplane.gnss.constants import C
from coplane.gnss.ephemeris import geometric_range
from coplane.gnss.lsq import chi2_threshold, w_tests
from coplane.gnss.measurements import PreparedEpoch, SatMeasurement
from coplane.gnss.weighting import pseudorange_sigma_m, rtklib_variance_m2, standalone_pseudorange_sigma_m
from coplane.gtime import GpsTime
from coplane.recording.model import NavData

Vec = NDArray[Any]  # numpy arithmetic widens dtypes; precise dtype hints only add noise
RaimMode = Literal["fde", "detect", "off"]


@dataclass(frozen=True)
class SppOptions:
    """Options; defaults are the ones coplane uses everywhere (documented in docs/gnss-models.md)."""

    elevation_mask_deg: float = 10.0
    cn0_mask_dbhz: float = 0.0
    iono: bool = True
    # "rtklib": BeiDou with the GPS Klobuchar scaled to B1I, as RTKLIB 2.4.3 does; "broadcast":
    # each system's own broadcast model (BDS ICD coefficients for BeiDou), the better default.
    iono_model: Literal["broadcast", "rtklib"] = "broadcast"
    tropo: bool = True
    weighting: Literal["cn0-elevation", "rtklib"] = "cn0-elevation"
    raim: RaimMode = "fde"
    false_alarm_probability: float = 1e-3
    max_exclusions: int = 4
    max_gdop: float = 30.0
    max_iterations: int = 12
    convergence_m: float = 1e-4


@dataclass(frozen=True)
class Dops:
    gdop: float
    pdop: float
    hdop: float
    vdop: float


@dataclass
class SppSolution:
    """An SPP result. `ok` False means no usable fix; `reason` says why."""

    time: GpsTime
    ok: bool
    reason: str | None = None
    position: Vec = field(default_factory=lambda: np.full(3, np.nan))
    clocks_m: dict[str, float] = field(default_factory=dict)
    covariance: Vec = field(default_factory=lambda: np.full((3, 3), np.nan))  # ECEF position, m^2
    dops: Dops | None = None
    used: tuple[str, ...] = ()
    excluded: tuple[str, ...] = ()
    residuals_m: dict[str, float] = field(default_factory=dict)
    sigmas_m: dict[str, float] = field(default_factory=dict)
    chi2: float = math.nan
    dof: int = 0
    iterations: int = 0

    @property
    def n_used(self) -> int:
        return len(self.used)


@dataclass
class _Fit:
    x: Vec
    systems: list[str]
    sats: list[SatMeasurement]
    v: Vec  # residuals y - h(x), m
    sigma: Vec
    a: Vec  # design matrix
    iterations: int
    converged: bool


def _predict(
    m: SatMeasurement,
    p: Vec,
    t: GpsTime,
    nav: NavData,
    opt: SppOptions,
    differential: bool,
    lat: float,
    lon: float,
    h: float,
    rot: Vec | None,
) -> tuple[float, Vec, float, float]:
    """Predicted pseudorange without receiver clock, unit line of sight, elevation, iono delay."""
    rng, e = geometric_range(m.state.pos, p)
    pred = rng - C * m.state.clock_s
    el = math.pi / 2
    iono = 0.0
    if not differential:
        pred += m.tgd_m
    if rot is not None:
        el = math.asin(max(-1.0, min(1.0, float(rot[2] @ e))))
        if not differential:
            az = math.atan2(float(rot[0] @ e), float(rot[1] @ e)) % (2 * math.pi)
            if opt.iono:
                if opt.iono_model == "rtklib" and m.system == "C" and "G" in nav.iono:
                    iono = klobuchar_gps_m(t, lat, lon, az, el, nav.iono["G"]) * GPS_L1_TO_BDS_B1I
                else:
                    iono = iono_delay_m(m.system, t, lat, lon, az, el, nav)
            if opt.tropo:
                pred += saastamoinen_m(lat, h, el)
            pred += iono
    return pred, e, el, iono


# RTKLIB pntpos adds these to its elevation model (rescode): code bias, broadcast-iono and
# Saastamoinen residual errors. Reproduced only in "rtklib" weighting, for like-for-like checks.
_RTKLIB_ERR_CBIAS_M = 0.3
_RTKLIB_ERR_BRDCI = 0.5
_RTKLIB_ERR_SAAS_M = 0.3


def _sigma(m: SatMeasurement, el: float, iono: float, opt: SppOptions, differential: bool) -> float:
    if opt.weighting == "rtklib":
        var = rtklib_variance_m2(el, m.system) + m.state.variance_m2 + _RTKLIB_ERR_CBIAS_M**2
        if not differential:
            var += (_RTKLIB_ERR_BRDCI * iono) ** 2 + (_RTKLIB_ERR_SAAS_M / (math.sin(el) + 0.1)) ** 2
        return math.sqrt(var)
    if differential:
        return pseudorange_sigma_m(el, m.cn0_dbhz, m.system)
    return standalone_pseudorange_sigma_m(el, m.cn0_dbhz, m.system, iono)


def _solve(
    sats: list[SatMeasurement],
    y: Vec,
    x0: Vec | None,
    t: GpsTime,
    nav: NavData,
    opt: SppOptions,
    differential: bool,
) -> _Fit | None:
    """Gauss-Newton on position + one clock per system present; None when under-determined."""
    systems = sorted({m.system for m in sats})
    nx = 3 + len(systems)
    x = np.zeros(nx)
    if x0 is not None:
        x[:3] = x0[:3]
    mask = math.radians(opt.elevation_mask_deg)
    active = list(range(len(sats)))
    v: Vec = np.zeros(0)
    a: Vec = np.zeros((0, nx))
    sig: Vec = np.zeros(0)
    converged = False
    it = 0
    while it < opt.max_iterations:
        it += 1
        p = x[:3]
        rot: Vec | None = None
        lat = lon = h = 0.0
        if float(p @ p) > 6.0e6**2:  # only once near the Earth's surface are el/atmosphere meaningful
            lat, lon, h = ecef_to_geodetic(p)
            rot = enu_rotation(lat, lon)
        rows, res, sg, keep = [], [], [], []
        for i, m in enumerate(sats):
            pred, e, el, iono = _predict(m, p, t, nav, opt, differential, lat, lon, h, rot)
            if rot is not None and el < mask:
                continue
            row = np.zeros(nx)
            row[:3] = -e
            k = systems.index(m.system)
            row[3 + k] = 1.0
            rows.append(row)
            res.append(y[i] - (pred + x[3 + k]))
            sg.append(_sigma(m, el, iono, opt, differential))
            keep.append(i)
        present = sorted({sats[i].system for i in keep})
        a = np.array(rows).reshape(-1, nx)
        # drop clock columns of systems that lost all their satellites to the mask
        cols = [0, 1, 2] + [3 + systems.index(s) for s in present]
        a = a[:, cols]
        if len(keep) < len(cols):
            return None
        v, sig = np.array(res), np.array(sg)
        w = 1.0 / sig
        dx, *_ = np.linalg.lstsq(a * w[:, None], v * w, rcond=None)
        full = np.zeros(nx)
        full[cols] = dx
        x += full
        active = keep
        if float(np.linalg.norm(dx[:3])) < opt.convergence_m:
            converged = True
            break
    # residuals at the final state
    p = x[:3]
    lat, lon, h = ecef_to_geodetic(p)
    rot = enu_rotation(lat, lon)
    final_sats = [sats[i] for i in active]
    systems_f = sorted({m.system for m in final_sats})
    nxf = 3 + len(systems_f)
    a = np.zeros((len(final_sats), nxf))
    v = np.zeros(len(final_sats))
    sig = np.zeros(len(final_sats))
    for j, i in enumerate(active):
        m = sats[i]
        pred, e, el, iono = _predict(m, p, t, nav, opt, differential, lat, lon, h, rot)
        a[j, :3] = -e
        a[j, 3 + systems_f.index(m.system)] = 1.0
        v[j] = y[i] - (pred + x[3 + systems.index(m.system)])
        sig[j] = _sigma(m, el, iono, opt, differential)
    xf = np.concatenate([x[:3], [x[3 + systems.index(s)] for s in systems_f]])
    return _Fit(xf, systems_f, final_sats, v, sig, a, it, converged)


def _dops(a: Vec, p: Vec) -> Dops:
    lat, lon, _ = ecef_to_geodetic(p)
    r = enu_rotation(lat, lon)
    g = a.copy()
    g[:, :3] = a[:, :3] @ r.T  # line of sight in ENU
    q = np.linalg.inv(g.T @ g)
    return Dops(
        gdop=float(math.sqrt(np.trace(q))),
        pdop=float(math.sqrt(q[0, 0] + q[1, 1] + q[2, 2])),
        hdop=float(math.sqrt(q[0, 0] + q[1, 1])),
        vdop=float(math.sqrt(q[2, 2])),
    )


def solve_spp(
    epoch: PreparedEpoch,
    nav: NavData,
    options: SppOptions | None = None,
    corrections_m: Mapping[str, float] | None = None,
    initial_position: Vec | None = None,
) -> SppSolution:
    """Solve one epoch. With `corrections_m` (DGNSS), only corrected satellites are used."""
    opt = options or SppOptions()
    differential = corrections_m is not None
    sats: list[SatMeasurement] = []
    for m in epoch.sats:
        if math.isfinite(m.cn0_dbhz) and m.cn0_dbhz < opt.cn0_mask_dbhz:
            continue
        if differential and m.sat not in corrections_m:  # type: ignore[operator]
            continue
        sats.append(m)
    if len(sats) < 4:
        return SppSolution(epoch.time, False, f"too few satellites: {len(sats)} < 4")
    excluded: list[str] = []
    x0 = initial_position
    while True:
        y = np.array([m.pseudorange_m - (corrections_m[m.sat] if corrections_m else 0.0) for m in sats])
        fit = _solve(sats, y, x0, epoch.time, nav, opt, differential)
        if fit is None:
            return SppSolution(
                epoch.time, False, f"too few satellites above the mask: {len(sats)}", excluded=tuple(excluded)
            )
        if not fit.converged:
            return SppSolution(epoch.time, False, "least squares did not converge", excluded=tuple(excluded))
        dof = len(fit.sats) - len(fit.x)
        chi = float(np.sum((fit.v / fit.sigma) ** 2))
        threshold = chi2_threshold(opt.false_alarm_probability, dof)
        passed = dof <= 0 or chi <= threshold
        if passed or opt.raim == "off":
            break
        if opt.raim == "detect" or len(excluded) >= opt.max_exclusions or dof < 2:
            return SppSolution(
                epoch.time,
                False,
                f"chi-square test failed: {chi:.1f} > {threshold:.1f} (dof {dof}, excluded {len(excluded)})",
                excluded=tuple(excluded),
            )
        worst = int(np.argmax(np.abs(w_tests(fit.a, fit.v, fit.sigma))))
        excluded.append(fit.sats[worst].sat)
        sats = [m for m in sats if m.sat != fit.sats[worst].sat]
        x0 = fit.x[:3]
    p = fit.x[:3]
    w = 1.0 / fit.sigma**2
    try:
        q = np.linalg.inv(fit.a.T @ (fit.a * w[:, None]))
        dops = _dops(fit.a, p)
    except np.linalg.LinAlgError:
        return SppSolution(epoch.time, False, "singular geometry", excluded=tuple(excluded))
    if dops.gdop > opt.max_gdop:
        return SppSolution(
            epoch.time, False, f"GDOP {dops.gdop:.1f} > {opt.max_gdop}", excluded=tuple(excluded)
        )
    return SppSolution(
        time=epoch.time,
        ok=True,
        position=p.copy(),
        clocks_m={s: float(fit.x[3 + k]) for k, s in enumerate(fit.systems)},
        covariance=q[:3, :3],
        dops=dops,
        used=tuple(m.sat for m in fit.sats),
        excluded=tuple(excluded),
        residuals_m={m.sat: float(fit.v[j]) for j, m in enumerate(fit.sats)},
        sigmas_m={m.sat: float(fit.sigma[j]) for j, m in enumerate(fit.sats)},
        chi2=chi,
        dof=dof,
        iterations=fit.iterations,
    )
