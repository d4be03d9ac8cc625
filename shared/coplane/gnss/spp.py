"""Single point positioning: weighted iterative least squares with RAIM fault detection/exclusion.

Model per satellite i (metres):  y_i = P_i - delta_i  =  |p - p_s|_sagnac + b_sys(i) - c*dts_i
                                                          [+ TGD_i + I_i + T_i when not differential]
with one receiver clock per constellation (GPS and BeiDou time differ by an unknown inter-system
bias). `delta_i` is a DGNSS correction (gnss.dgnss) or 0. Fault detection is the global chi-square
test on the weighted residuals; exclusion removes the satellite with the largest standardised
residual (Baarda's w-test) and repeats, so it costs one solve per exclusion rather than RTKLIB's
one solve per candidate. A fix that still fails is returned as "no solution" with the reason,
never as a bad position.

Iterations start at the receiver's previous fix with the satellite models (elevation, delay,
sigma) its previous fit ended with (`sat_models.SatModels`); once converged, the models are
evaluated there and the fit takes one more step, so a fit ends with models evaluated within
`_ATMOSPHERE_EXACT_M` of its position: the Doppler rows and the node message reuse that one
evaluation (`SppSolution.model_position`). That is about one evaluation per epoch, where there
were three or four (SPP's, then the message's own), and the fit agrees with RTKLIB's `pntpos`,
which evaluates them at every iteration, as before (tests/gnss/test_spp_real.py).
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
from coplane.gnss.lsq import chi2_threshold, weighted_solve, worst_rows
from coplane.gnss.measurements import PreparedEpoch, SatMeasurement
from coplane.gnss.sat_models import FitAtmosphere, SatModels
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
    # where the fit's elevations, atmosphere and weights were evaluated, within
    # _ATMOSPHERE_EXACT_M of `position`: the Doppler rows and the node message model the
    # satellites at this point too, so all three share one evaluation (geometry's caches)
    model_position: Vec = field(default_factory=lambda: np.full(3, np.nan))
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
    models: SatModels | None = None  # each solved satellite as modelled at `model_position`

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
# ...and a fit that converged on an atmosphere evaluated further away than this iterates once
# more on one evaluated where it converged: 0.1 m moves an elevation by 5 nrad and a 10-degree
# tropospheric delay by 0.2 mm.
_ATMOSPHERE_EXACT_M = 0.1
# The smallest receiver-satellite range from near the surface (GPS and BeiDou MEO/IGSO/GEO), and
# a bound on how much a range error moves the position (the GDOP limit's): see `_converged`.
_MIN_RANGE_M = 1.9e7
_GN_GAIN = 30.0


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


def _converged(step_m: float, near_surface: bool, convergence_m: float) -> bool:
    """Whether the fit after a position step of `step_m` is within `convergence_m` of where the
    iterations end. A range's error after a linearised step d is at most d^2 / (2 rho), rho the
    receiver-satellite range (over 19,000 km from the surface for GPS and BeiDou), and at most
    `_GN_GAIN` times that reaches the position (a common part goes into the clocks): so near the
    surface a step of up to ~10 m already lands within 1e-4 m, and the confirming iteration
    (most of an epoch's iterations) is skipped."""
    if step_m < convergence_m:
        return True
    return near_surface and _GN_GAIN * step_m * step_m / (2.0 * _MIN_RANGE_M) < convergence_m


def _near_surface(p: Vec) -> bool:
    """Whether `p` is where the atmosphere and the elevation mask mean something (> 6000 km)."""
    return float(p @ p) > 6.0e6**2


def _solve(
    epoch: PreparedEpoch,
    idx: Sequence[int],
    y: Vec,
    x0: Vec | None,
    nav: NavData,
    opt: SppOptions,
    differential: bool,
    prior: FitAtmosphere | None = None,
    models: SatModels | None = None,
) -> tuple[_Fit | None, FitAtmosphere]:
    """Gauss-Newton on position + one clock per system present; no fit when under-determined.

    Solves `epoch.sats[idx]`; the atmosphere is evaluated on the whole epoch's view (the Doppler
    rows and the node message ask for the same one at the fix). `prior` (for exactly those
    satellites) carries the atmosphere of a previous solve over, so a re-solve after a fault
    exclusion, which starts where the last one ended, does not evaluate it again; else the
    receiver's previous `models` start the iterations when they cover these satellites.
    Returns the fit and the atmosphere of the solved satellites where the fit ended.
    """
    sats = [epoch.sats[i] for i in idx]
    t = epoch.time
    systems = sorted({m.system for m in sats})
    nx = 3 + len(systems)
    n = len(sats)
    sat_systems = [m.system for m in sats]
    sel = np.asarray(idx, dtype=int)
    sat_pos = epoch.sat_pos[sel]
    sat_clk_m = C * np.array([m.state.clock_s for m in sats])
    tgd = np.zeros(n) if differential else np.array([m.tgd_m for m in sats])
    sys_col = np.array([3 + systems.index(s) for s in sat_systems])
    x = np.zeros(nx)
    if x0 is not None:
        x[:3] = x0[:3]
    mask = math.radians(opt.elevation_mask_deg)

    def refresh(p: Vec) -> FitAtmosphere:
        view = sky_view(epoch.sat_pos, p)
        el = view.el_rad[sel]
        if differential:
            return FitAtmosphere(p.copy(), el, tgd, _sigmas(sats, el, np.zeros(n), opt, True))
        iono, tropo = broadcast_delays(epoch.systems, t, view, nav, opt.iono, opt.tropo, opt.iono_model)
        iono, tropo = iono[sel], tropo[sel]
        return FitAtmosphere(p.copy(), el, tgd + iono + tropo, _sigmas(sats, el, iono, opt, False))

    def distance_from_atmos(p: Vec) -> float:
        return math.inf if atmos.at is None else math.dist(p.tolist(), atmos.at.tolist())

    if prior is None and models is not None and _near_surface(x[:3]):
        prior = models.atmosphere(t, sats, tgd, differential)
    if prior is None:
        if _near_surface(x[:3]):
            prior = refresh(x[:3].copy())
        else:  # before the position is near the surface: no atmosphere, no mask, zenith weights (RTKLIB)
            el = np.full(n, math.pi / 2)
            prior = FitAtmosphere(None, el, tgd.copy(), _sigmas(sats, el, np.zeros(n), opt, differential))
    atmos = prior
    keep = np.ones(n, dtype=bool)
    converged = False
    it = 0
    a = np.zeros((n, nx))
    a[np.arange(n), sys_col] = 1.0
    kept_before: Vec | None = None
    cols: list[int] = []
    while it < opt.max_iterations:
        it += 1
        p = x[:3]
        near_surface = _near_surface(p)
        if near_surface and not atmos.carried and distance_from_atmos(p) > _ATMOSPHERE_REFRESH_M:
            atmos = refresh(p)
        rng, e = sagnac_ranges(sat_pos, p)
        keep = atmos.el >= mask if near_surface else np.ones(n, dtype=bool)
        if kept_before is None or not np.array_equal(keep, kept_before):  # the columns it solves
            present = sorted({sat_systems[i] for i in np.flatnonzero(keep)})
            cols = [0, 1, 2] + [3 + systems.index(s) for s in present]
            kept_before = keep
        if int(keep.sum()) < len(cols):
            return None, atmos
        v = y - (rng - sat_clk_m + atmos.delay + x[sys_col])
        a[:, :3] = -e
        dx = weighted_solve(a[keep][:, cols], v[keep], 1.0 / atmos.sig[keep])
        x[cols] += dx
        if _converged(float(np.linalg.norm(dx[:3])), near_surface, opt.convergence_m):
            if distance_from_atmos(x[:3]) > _ATMOSPHERE_EXACT_M:
                atmos = refresh(x[:3].copy())  # converged on a stale atmosphere: once more, evaluated here
                continue
            converged = True
            break
    # residuals and weights at the final state, with the atmosphere evaluated within
    # _ATMOSPHERE_EXACT_M of it (only an unconverged fit can still be further away)
    p = x[:3].copy()
    if distance_from_atmos(p) > _ATMOSPHERE_EXACT_M:
        atmos = refresh(p)
    rng, e = sagnac_ranges(sat_pos, p)
    kept = np.flatnonzero(keep)
    final_sats = [sats[i] for i in kept]
    systems_f = sorted({m.system for m in final_sats})
    af = np.zeros((len(kept), 3 + len(systems_f)))
    af[:, :3] = -e[kept]
    af[np.arange(len(kept)), [3 + systems_f.index(m.system) for m in final_sats]] = 1.0
    v = y[kept] - (rng[kept] - sat_clk_m[kept] + atmos.delay[kept] + x[sys_col[kept]])
    xf = np.concatenate([x[:3], [x[3 + systems.index(s)] for s in systems_f]])
    return _Fit(xf, systems_f, final_sats, v, atmos.sig[kept].copy(), af, it, converged), atmos


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


def _dof_without(fit: _Fit, group: list[SatMeasurement]) -> int:
    """The redundancy left once `group` is excluded: its rows go, and so does the clock of a
    system that loses its last satellite."""
    gone = {id(m) for m in group}
    left = [m for m in fit.sats if id(m) not in gone]
    return len(left) - 3 - len({m.system for m in left})


def _too_few(n: int, epoch: PreparedEpoch) -> str:
    """Why an epoch has no fix with `n` < 4 satellites: a receiver that tracks enough of them but
    has no ephemeris for them (a navigation file of another day) is told apart from a poor sky."""
    no_eph = sum(1 for _, why in epoch.dropped if why == "no usable ephemeris")
    if no_eph and n + no_eph >= 4:
        return f"too few satellites with an ephemeris: {n} < 4 ({no_eph} tracked without one)"
    return f"too few satellites: {n} < 4"


def solve_spp(
    epoch: PreparedEpoch,
    nav: NavData,
    options: SppOptions | None = None,
    corrections_m: Mapping[str, float] | None = None,
    initial_position: Vec | None = None,
    models: SatModels | None = None,
) -> SppSolution:
    """Solve one epoch. With `corrections_m` (DGNSS), only corrected satellites are used.

    `initial_position` and `models` (the receiver's previous fix and its `SppSolution.models`)
    are where the iterations start; the fit does not depend on them.
    """
    opt = options or SppOptions()
    differential = corrections_m is not None
    idx: list[int] = []  # the satellites solved, as indices into epoch.sats
    for i, m in enumerate(epoch.sats):
        if math.isfinite(m.cn0_dbhz) and m.cn0_dbhz < opt.cn0_mask_dbhz:
            continue
        if differential and m.sat not in corrections_m:  # type: ignore[operator]
            continue
        idx.append(i)
    sats = [epoch.sats[i] for i in idx]
    if len(sats) < 4:
        return SppSolution(epoch.time, False, _too_few(len(sats), epoch))
    excluded: list[str] = []
    x0 = initial_position
    atmos: FitAtmosphere | None = None
    y = np.array([m.pseudorange_m - (corrections_m[m.sat] if corrections_m else 0.0) for m in sats])
    seen: dict[str, tuple[float, float, float, float]] = {}  # every satellite as last modelled
    now = epoch.time.seconds
    while True:
        fit, atmos = _solve(epoch, idx, y, x0, nav, opt, differential, atmos, models)
        if atmos.at is not None:
            delay = atmos.delay.tolist() if differential else (atmos.delay - [m.tgd_m for m in sats]).tolist()
            rows = zip(atmos.el.tolist(), delay, atmos.sig.tolist(), [now] * len(sats), strict=True)
            seen.update(zip((m.sat for m in sats), rows, strict=True))
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
        # the worst satellite, with any whose test is the same one (a system's two satellites),
        # excluded only if the fit after it can still be tested and the limit is kept
        group = [fit.sats[j] for j in worst_rows(fit.a, fit.v, fit.sigma)] if opt.raim == "fde" else []
        if not group or len(excluded) + len(group) > opt.max_exclusions or _dof_without(fit, group) < 1:
            return SppSolution(
                epoch.time,
                False,
                f"chi-square test failed: {chi:.1f} > {threshold:.1f} (dof {dof}, excluded {len(excluded)}"
                + (f", cannot exclude {len(group)} more)" if group else ")"),
                excluded=tuple(excluded),
            )
        for m in group:
            i = sats.index(m)
            excluded.append(m.sat)
            sats = sats[:i] + sats[i + 1 :]
            idx = idx[:i] + idx[i + 1 :]
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
        model_position=atmos.at.copy() if atmos.at is not None else p.copy(),
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
        models=SatModels(epoch.time, differential, seen),
    )
