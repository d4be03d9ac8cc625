"""Doppler velocity: least squares for receiver velocity and clock drift (paper eqs. 28-34).

Range-rate model per satellite (RINEX Doppler sign: range rate = -lambda * D):
    -lambda*D_i = (v_s,i - v) . e_i + sagnac_rate_i + drift - c*dts_dot_i
with e_i the unit vector receiver->satellite at the SPP position (eq. 29) and one common clock
drift (the oscillator is shared by all constellations). Outliers (e.g. NLOS Doppler) are removed by
the same global test + w-test exclusion as SPP.

Few satellites (`DopplerOptions.few_satellites`, on by default; the paper needs 5): 3 or 4
Doppler measurements leave the four unknowns without redundancy. A road vehicle adds two
pseudo-measurements: its vertical speed is about zero (grade x speed), and its oscillator's drift
wanders slowly from the last value measured with a full sky (`DriftPrior`; about 0.1 m/s per
second on a u-blox F9P TCXO, docs/fgo.md). Without a velocity in such stretches the fusion graph
can only carry the last one forward, and a real car's track ran 50-140 m away (docs/fgo.md, "Few
satellites on a real receiver", which also has what it did on the simulator's training seeds).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from coplane.errors import require_finite_positive
from coplane.geo import up_vector
from coplane.gnss.constants import OMEGA_E_GPS, C
from coplane.gnss.geometry import sky_view
from coplane.gnss.lsq import chi2_threshold, weighted_solve, worst_rows
from coplane.gnss.measurements import PreparedEpoch, SatMeasurement
from coplane.gnss.standstill import DopplerNoise, StandstillOptions, standstill_test
from coplane.gnss.weighting import doppler_sigma_mps
from coplane.gtime import GpsTime
from coplane.typing import AnyArray as Vec


@dataclass(frozen=True)
class DopplerOptions:
    elevation_mask_deg: float = 10.0
    false_alarm_probability: float = 1e-3
    max_exclusions: int = 4
    min_satellites: int = 5  # 4 unknowns + 1 for a residual test
    # Few-satellite solve (module docstring): with fewer than min_satellites but at least
    # few_min_satellites measurements, solve with a vertical-speed pseudo-measurement of sigma
    # vertical_speed_sigma_mps (a 6 % grade at 30 km/h) and, when a drift was measured within
    # drift_max_age_s, a drift pseudo-measurement whose sigma grows by drift_wander_mps_per_s per
    # second of its age (the F9P's measured wander). At least one redundant row is required.
    few_satellites: bool = True
    few_min_satellites: int = 3
    vertical_speed_sigma_mps: float = 0.5
    drift_wander_mps_per_s: float = 0.1
    drift_max_age_s: float = 60.0
    # ... and keep a few-satellite velocity only when its weakest direction's 1-sigma is within
    # this (m/s). The estimators weigh every node velocity alike (the methods' sigma_v), so it
    # must be about as strong as a full-sky one (median 0.47, p90 0.73 m/s on the KLT car, docs/fgo.md).
    # Three satellites nearly in one plane leave one horizontal speed to the drift memory alone,
    # at several m/s with errors correlated over the whole stretch: dead reckoning on it ran a
    # static antenna 420 m away.
    few_max_sigma_mps: float = 0.6
    # Before that solve, fewer than min_satellites Doppler rows test whether the receiver stands
    # (coplane.gnss.standstill): a passed test is a zero velocity, flagged `standstill`.
    standstill: StandstillOptions = field(default_factory=StandstillOptions)

    def __post_init__(self) -> None:
        # 2 satellites + 2 pseudo-rows cannot leave the redundant row the solve needs
        if self.few_min_satellites < 3:
            raise ValueError(
                f"DopplerOptions.few_min_satellites must be >= 3, got {self.few_min_satellites!r}"
            )
        require_finite_positive(
            self,
            ("vertical_speed_sigma_mps", "drift_wander_mps_per_s", "drift_max_age_s", "few_max_sigma_mps"),
            "DopplerOptions.",
        )


@dataclass(frozen=True)
class DriftPrior:
    """A receiver's last clock drift measured with a full sky (m/s), and when."""

    drift_mps: float
    time: GpsTime


@dataclass
class DopplerVelocity:
    time: GpsTime
    ok: bool
    reason: str | None = None
    velocity_mps: Vec = field(default_factory=lambda: np.full(3, np.nan))  # ECEF
    drift_mps: float = math.nan
    covariance: Vec = field(default_factory=lambda: np.full((3, 3), np.nan))
    used: tuple[str, ...] = ()
    excluded: tuple[str, ...] = ()
    residuals_mps: dict[str, float] = field(default_factory=dict)
    few_satellites: bool = False  # solved with the pseudo-measurements of the few-satellite mode
    standstill: bool = False  # zero by coplane.gnss.standstill's test, not solved
    chi2: float = math.nan  # the accepted solve's sum of squared normalised residuals ...
    dof: int = 0  # ... and its redundancy (0: not a least-squares solve)


def _rows(epoch: PreparedEpoch, p: Vec, mask: float) -> tuple[list[SatMeasurement], Vec, Vec, Vec]:
    """Satellites with a Doppler above the mask, design rows, range-rate residuals, sigmas.

    The view is of the whole epoch (at the SPP fix it is the one SPP ended with, cached)."""
    if not epoch.sats:
        return [], np.zeros((0, 4)), np.zeros(0), np.zeros(0)
    view = sky_view(epoch.sat_pos, p)
    keep = (view.el_rad >= mask) & np.array([math.isfinite(m.doppler_hz) for m in epoch.sats], dtype=bool)
    use = [m for m, k in zip(epoch.sats, keep.tolist(), strict=True) if k]
    if not use:
        return [], np.zeros((0, 4)), np.zeros(0), np.zeros(0)
    ps, e, el = epoch.sat_pos[keep], view.los[keep], view.el_rad[keep]
    vs = np.array([m.state.vel for m in use]).reshape(-1, 3)
    rate = np.array([m.range_rate_mps for m in use])
    drift = np.array([m.state.drift_s_per_s for m in use])
    # Sagnac rate: the time derivative of geometry.sagnac_ranges' term w/c (xs yr - ys xr), its
    # satellite-velocity part here and its receiver-velocity part in the design matrix. RTKLIB's
    # resdop has the opposite sign (RTKLIB issue #764; GTSAM's DopplerFactor was fixed the same way).
    sag_s = OMEGA_E_GPS / C * (vs[:, 0] * p[1] - vs[:, 1] * p[0])
    y = rate - (np.einsum("ij,ij->i", vs, e) + sag_s - C * drift)
    a = np.column_stack(
        [
            -e[:, 0] - OMEGA_E_GPS / C * ps[:, 1],
            -e[:, 1] + OMEGA_E_GPS / C * ps[:, 0],
            -e[:, 2],
            np.ones(len(use)),
        ]
    )
    cn0 = np.array([m.cn0_dbhz for m in use])
    return use, a, y, doppler_sigma_mps(el, cn0, [m.system for m in use])


def _pseudo_rows(t: GpsTime, p: Vec, opt: DopplerOptions, prior: DriftPrior | None) -> tuple[Vec, Vec, Vec]:
    """The few-satellite mode's pseudo-measurements (module docstring): rows, values, sigmas."""
    drift = _drift_rows(t, opt, prior)
    return (
        np.vstack([np.append(up_vector(p), 0.0), drift[0]]),
        np.concatenate([[0.0], drift[1]]),
        np.concatenate([[opt.vertical_speed_sigma_mps], drift[2]]),
    )


def _drift_rows(t: GpsTime, opt: DopplerOptions, prior: DriftPrior | None) -> tuple[Vec, Vec, Vec]:
    """The drift memory's pseudo-measurement while it is recent (else none): rows, values, sigmas."""
    age = t - prior.time if prior is not None else math.inf
    if prior is None or not 0.0 <= age <= opt.drift_max_age_s:
        return np.zeros((0, 4)), np.zeros(0), np.zeros(0)
    sigma = opt.drift_wander_mps_per_s * max(age, 1.0)
    return np.array([[0.0, 0.0, 0.0, 1.0]]), np.array([prior.drift_mps]), np.array([sigma])


def _standing(
    t: GpsTime,
    sats: list[SatMeasurement],
    a: Vec,
    y: Vec,
    sig: Vec,
    p: Vec,
    opt: DopplerOptions,
    prior: DriftPrior | None,
    noise: DopplerNoise | None,
) -> DopplerVelocity | None:
    """A zero velocity when the few Doppler rows, with the drift memory's row, pass the
    standstill test (coplane.gnss.standstill) at the receiver's own Doppler noise; None
    otherwise. Its covariance is the square of the speed the test could miss: a bound, not a
    least-squares spread."""
    extra = _drift_rows(t, opt, prior)  # a level-road row would add nothing to v = 0
    scale = math.sqrt((noise or DopplerNoise()).factor(opt.standstill))
    still = standstill_test(
        np.vstack([a, extra[0]]),
        np.concatenate([y, extra[1]]),
        np.concatenate([sig * scale, extra[2]]),
        up_vector(p),
        opt.standstill,
    )
    if still is None:
        return None
    return DopplerVelocity(
        time=t,
        ok=True,
        velocity_mps=np.zeros(3),
        drift_mps=still.drift_mps,
        covariance=np.eye(3) * still.detectable_speed_mps**2,
        used=tuple(m.sat for m in sats),
        residuals_mps={m.sat: float(still.residuals_mps[k]) for k, m in enumerate(sats)},
        few_satellites=True,
        standstill=True,
    )


def solve_doppler_velocity(
    epoch: PreparedEpoch,
    position: Vec,
    options: DopplerOptions | None = None,
    drift_prior: DriftPrior | None = None,
    noise: DopplerNoise | None = None,
) -> DopplerVelocity:
    """Velocity and drift at a known (SPP) position. Linear: one weighted solve per exclusion.

    `drift_prior` (the receiver's drift memory, `epoch_solver.next_drift_prior`) and `noise`
    (its learned Doppler noise, for the standstill test) are used only with few satellites
    (`DopplerOptions.few_satellites`).
    """
    opt = options or DopplerOptions()
    p = np.asarray(position, dtype=float)
    sats, a_sat, y_sat, sig_sat = _rows(epoch, p, math.radians(opt.elevation_mask_deg))
    if opt.few_satellites and opt.standstill.enabled and 2 <= len(sats) < opt.min_satellites:
        still = _standing(epoch.time, sats, a_sat, y_sat, sig_sat, p, opt, drift_prior, noise)
        if still is not None:
            return still
    pseudo: tuple[Vec, Vec, Vec] | None = None  # built only when an epoch has too few satellites
    excluded: list[str] = []
    while True:
        n = len(sats)
        few = n < opt.min_satellites
        if few and opt.few_satellites and pseudo is None:
            pseudo = _pseudo_rows(epoch.time, p, opt, drift_prior)
        if few and (
            pseudo is None or n < opt.few_min_satellites or n + len(pseudo[1]) < 5  # 4 unknowns + a test
        ):
            return DopplerVelocity(
                epoch.time,
                False,
                f"too few Doppler measurements: {n} < {opt.min_satellites}",
                excluded=tuple(excluded),
            )
        if few and pseudo is not None:
            a, y, sig = (
                np.vstack([a_sat, pseudo[0]]),
                np.concatenate([y_sat, pseudo[1]]),
                np.concatenate([sig_sat, pseudo[2]]),
            )
        else:
            a, y, sig = a_sat, y_sat, sig_sat
        x = weighted_solve(a, y, 1.0 / sig)
        v = y - a @ x
        dof = len(y) - 4
        chi = float(np.sum((v / sig) ** 2))
        if chi <= chi2_threshold(opt.false_alarm_probability, dof):
            break
        # the worst satellite (never a pseudo row), with any whose test is the same one: with one
        # redundant row that is every satellite, and which one is faulty cannot be told
        group = worst_rows(a, v, sig, rows=n)
        if len(group) == n:
            return DopplerVelocity(
                epoch.time,
                False,
                f"Doppler residual test failed and no satellite can be told faulty (chi2 {chi:.1f}, dof {dof})",
                excluded=tuple(excluded),
            )
        if len(excluded) + len(group) > opt.max_exclusions:
            return DopplerVelocity(
                epoch.time,
                False,
                f"Doppler residual test failed after {len(excluded)} exclusions"
                f" (cannot exclude {len(group)} more)",
                excluded=tuple(excluded),
            )
        excluded.extend(sats[j].sat for j in group)
        keep = ~np.isin(np.arange(n), group)
        sats = [m for k, m in enumerate(sats) if keep[k]]
        a_sat, y_sat, sig_sat = a_sat[keep], y_sat[keep], sig_sat[keep]
    q = np.linalg.inv(a.T @ (a / sig[:, None] ** 2))
    worst_sigma = math.sqrt(max(float(np.linalg.eigvalsh(q[:3, :3])[-1]), 0.0)) if few else 0.0
    if worst_sigma > opt.few_max_sigma_mps:
        return DopplerVelocity(
            epoch.time,
            False,
            f"few-satellite velocity too weak: 1-sigma {worst_sigma:.2f} m/s > {opt.few_max_sigma_mps} m/s",
            excluded=tuple(excluded),
        )
    return DopplerVelocity(
        time=epoch.time,
        ok=True,
        velocity_mps=x[:3].copy(),
        drift_mps=float(x[3]),
        covariance=q[:3, :3],
        used=tuple(m.sat for m in sats),
        excluded=tuple(excluded),
        residuals_mps={m.sat: float(v[k]) for k, m in enumerate(sats)},
        few_satellites=few,
        chi2=chi,
        dof=dof,
    )
