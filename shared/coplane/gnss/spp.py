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
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from coplane.geo import ecef_to_geodetic, enu_rotation
from coplane.gnss.constants import C
from coplane.gnss.geometry import broadcast_delays, sagnac_ranges, sky_view
from coplane.gnss.lsq import chi2_threshold, w_tests
from coplane.gnss.measurements import PreparedEpoch, SatMeasurement
from coplane.gnss.weighting import pseudorange_sigma_m, rtklib_variance_m2, standalone_pseudorange_sigma_m
from coplane.gtime import GpsTime
from coplane.recording.model import NavData
from coplane.typing import AnyArray as Vec

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


# RTKLIB pntpos adds these to its elevation model (rescode): code bias, broadcast-iono and
# Saastamoinen residual errors. Reproduced only in "rtklib" weighting, for like-for-like checks.
_RTKLIB_ERR_CBIAS_M = 0.3
_RTKLIB_ERR_BRDCI = 0.5
_RTKLIB_ERR_SAAS_M = 0.3

# Atmosphere and weights are re-evaluated only when the position moved more than this since the
# last evaluation: their sensitivity to position is millimetres per kilometre, and evaluating them
# every Gauss-Newton iteration for every satellite was most of SPP's cost.
_ATMOSPHERE_REFRESH_M = 1000.0


def _sigmas(sats: Sequence[SatMeasurement], el: Vec, iono: Vec, opt: SppOptions, differential: bool) -> Vec:
    """Pseudorange 1-sigma (m) of each satellite at elevations `el` with broadcast iono `iono`."""
    systems = [m.system for m in sats]
    if opt.weighting == "rtklib":
        var_eph = np.array([m.state.variance_m2 for m in sats])
        var = rtklib_variance_m2(el, systems) + var_eph + _RTKLIB_ERR_CBIAS_M**2
        if not differential:
            var = var + (_RTKLIB_ERR_BRDCI * iono) ** 2 + (_RTKLIB_ERR_SAAS_M / (np.sin(el) + 0.1)) ** 2
        return np.sqrt(var)
    cn0 = np.array([m.cn0_dbhz for m in sats])
    if differential:
        return pseudorange_sigma_m(el, cn0, systems)
    return standalone_pseudorange_sigma_m(el, cn0, systems, iono)


@dataclass
class _Atmos:
    """Per-satellite elevation, model delay and sigma, evaluated at position `at` (None: not yet)."""

    at: Vec | None
    el: Vec
    delay: Vec  # TGD + iono + tropo (0 with DGNSS), m
    sig: Vec

    def without(self, i: int) -> _Atmos:
        keep = np.arange(len(self.el)) != i
        return _Atmos(self.at, self.el[keep], self.delay[keep], self.sig[keep])


def _gauss_newton_step(a: Vec, v: Vec, w: Vec) -> Vec:
    """Weighted least-squares step; the normal equations are well conditioned for SPP's 4-6
    unknowns and several times cheaper than lstsq's SVD, which stays the fallback when singular."""
    aw = a * w[:, None]
    try:
        return np.linalg.solve(aw.T @ aw, aw.T @ (v * w))
    except np.linalg.LinAlgError:
        return np.linalg.lstsq(aw, v * w, rcond=None)[0]


def _solve(
    sats: list[SatMeasurement],
    y: Vec,
    x0: Vec | None,
    t: GpsTime,
    nav: NavData,
    opt: SppOptions,
    differential: bool,
    prior: _Atmos | None = None,
) -> tuple[_Fit | None, _Atmos]:
    """Gauss-Newton on position + one clock per system present; no fit when under-determined.

    `prior` (for exactly `sats`) carries the atmosphere of a previous solve over, so a re-solve
    after a fault exclusion, which starts where the last one ended, does not evaluate it again.
    Returns the fit and the atmosphere of all `sats` where the fit ended.
    """
    systems = sorted({m.system for m in sats})
    nx = 3 + len(systems)
    n = len(sats)
    sat_systems = [m.system for m in sats]
    sat_pos = np.array([m.state.pos for m in sats])
    sat_clk_m = C * np.array([m.state.clock_s for m in sats])
    tgd = np.zeros(n) if differential else np.array([m.tgd_m for m in sats])
    sys_col = np.array([3 + systems.index(s) for s in sat_systems])
    x = np.zeros(nx)
    if x0 is not None:
        x[:3] = x0[:3]
    mask = math.radians(opt.elevation_mask_deg)
    if prior is None:
        # before the position is near the surface: no atmosphere, no mask, zenith weights (RTKLIB)
        el = np.full(n, math.pi / 2)
        prior = _Atmos(None, el, tgd.copy(), _sigmas(sats, el, np.zeros(n), opt, differential))
    atmos = prior
    keep = np.ones(n, dtype=bool)
    converged = False
    it = 0

    def refresh(p: Vec) -> _Atmos:
        view = sky_view(sat_pos, p)
        if differential:
            return _Atmos(p.copy(), view.el_rad, tgd, _sigmas(sats, view.el_rad, np.zeros(n), opt, True))
        iono, tropo = broadcast_delays(sat_systems, t, view, nav, opt.iono, opt.tropo, opt.iono_model)
        return _Atmos(p.copy(), view.el_rad, tgd + iono + tropo, _sigmas(sats, view.el_rad, iono, opt, False))

    def distance_from_atmos(p: Vec) -> float:
        return math.inf if atmos.at is None else float(np.linalg.norm(p - atmos.at))

    a = np.zeros((n, nx))
    a[np.arange(n), sys_col] = 1.0
    while it < opt.max_iterations:
        it += 1
        p = x[:3]
        near_surface = float(p @ p) > 6.0e6**2
        if near_surface and distance_from_atmos(p) > _ATMOSPHERE_REFRESH_M:
            atmos = refresh(p)
        rng, e = sagnac_ranges(sat_pos, p)
        keep = atmos.el >= mask if near_surface else np.ones(n, dtype=bool)
        present = sorted({sat_systems[i] for i in np.flatnonzero(keep)})
        cols = [0, 1, 2] + [3 + systems.index(s) for s in present]
        if int(keep.sum()) < len(cols):
            return None, atmos
        v = y - (rng - sat_clk_m + atmos.delay + x[sys_col])
        a[:, :3] = -e
        dx = _gauss_newton_step(a[keep][:, cols], v[keep], 1.0 / atmos.sig[keep])
        x[cols] += dx
        if float(np.linalg.norm(dx[:3])) < opt.convergence_m:
            if distance_from_atmos(x[:3]) > 1.0:
                atmos = refresh(x[:3].copy())  # converged on a stale atmosphere: once more, evaluated here
                continue
            converged = True
            break
    # residuals and weights at the final state, with the atmosphere evaluated there (a millimetre
    # away from where it was last evaluated changes nothing: elevations move by nanoradians)
    p = x[:3].copy()
    if distance_from_atmos(p) > 1e-3:
        atmos = refresh(p)
    rng, e = sagnac_ranges(sat_pos, p)
    idx = np.flatnonzero(keep)
    final_sats = [sats[i] for i in idx]
    systems_f = sorted({m.system for m in final_sats})
    af = np.zeros((len(idx), 3 + len(systems_f)))
    af[:, :3] = -e[idx]
    af[np.arange(len(idx)), [3 + systems_f.index(m.system) for m in final_sats]] = 1.0
    v = y[idx] - (rng[idx] - sat_clk_m[idx] + atmos.delay[idx] + x[sys_col[idx]])
    xf = np.concatenate([x[:3], [x[3 + systems.index(s)] for s in systems_f]])
    return _Fit(xf, systems_f, final_sats, v, atmos.sig[idx].copy(), af, it, converged), atmos


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
    atmos: _Atmos | None = None
    y = np.array([m.pseudorange_m - (corrections_m[m.sat] if corrections_m else 0.0) for m in sats])
    while True:
        fit, atmos = _solve(sats, y, x0, epoch.time, nav, opt, differential, atmos)
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
        worst = fit.sats[int(np.argmax(np.abs(w_tests(fit.a, fit.v, fit.sigma))))]
        excluded.append(worst.sat)
        i = sats.index(worst)
        sats = sats[:i] + sats[i + 1 :]
        y = np.delete(y, i)
        atmos = atmos.without(i)
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
