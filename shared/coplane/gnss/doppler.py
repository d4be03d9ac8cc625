"""Doppler velocity: least squares for receiver velocity and clock drift (paper eqs. 28-34).

Range-rate model per satellite (RINEX Doppler sign: range rate = -lambda * D):
    -lambda*D_i = (v_s,i - v) . e_i + sagnac_rate_i + drift - c*dts_dot_i
with e_i the unit vector receiver->satellite at the SPP position (eq. 29) and one common clock
drift (the oscillator is shared by all constellations). Outliers (e.g. NLOS Doppler) are removed by
the same global test + w-test exclusion as SPP.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from coplane.gnss.constants import OMEGA_E_GPS, C
from coplane.gnss.geometry import sky_view
from coplane.gnss.lsq import chi2_threshold, w_tests
from coplane.gnss.measurements import PreparedEpoch, SatMeasurement
from coplane.gnss.weighting import doppler_sigma_mps
from coplane.gtime import GpsTime
from coplane.typing import AnyArray as Vec


@dataclass(frozen=True)
class DopplerOptions:
    elevation_mask_deg: float = 10.0
    false_alarm_probability: float = 1e-3
    max_exclusions: int = 4
    min_satellites: int = 5  # 4 unknowns + 1 for a residual test


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


def _rows(sats: list[SatMeasurement], p: Vec, mask: float) -> tuple[list[SatMeasurement], Vec, Vec, Vec]:
    """Satellites with a Doppler above the mask, design rows, range-rate residuals, sigmas."""
    sats = [m for m in sats if math.isfinite(m.doppler_hz)]
    if not sats:
        return [], np.zeros((0, 4)), np.zeros(0), np.zeros(0)
    ps = np.array([m.state.pos for m in sats])
    view = sky_view(ps, p)
    keep = view.el_rad >= mask
    use = [m for m, k in zip(sats, keep, strict=True) if k]
    ps, e, el = ps[keep], view.los[keep], view.el_rad[keep]
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


def solve_doppler_velocity(
    epoch: PreparedEpoch, position: Vec, options: DopplerOptions | None = None
) -> DopplerVelocity:
    """Velocity and drift at a known (SPP) position. Linear: one weighted solve per exclusion."""
    opt = options or DopplerOptions()
    p = np.asarray(position, dtype=float)
    sats, a, y, sig = _rows(list(epoch.sats), p, math.radians(opt.elevation_mask_deg))
    excluded: list[str] = []
    while True:
        if len(sats) < opt.min_satellites:
            return DopplerVelocity(
                epoch.time,
                False,
                f"too few Doppler measurements: {len(sats)} < {opt.min_satellites}",
                excluded=tuple(excluded),
            )
        w = 1.0 / sig
        x, *_ = np.linalg.lstsq(a * w[:, None], y * w, rcond=None)
        v = y - a @ x
        dof = len(sats) - 4
        chi = float(np.sum((v / sig) ** 2))
        if chi <= chi2_threshold(opt.false_alarm_probability, dof):
            break
        if len(excluded) >= opt.max_exclusions:
            return DopplerVelocity(
                epoch.time,
                False,
                f"Doppler residual test failed after {len(excluded)} exclusions",
                excluded=tuple(excluded),
            )
        worst = int(np.argmax(np.abs(w_tests(a, v, sig))))
        excluded.append(sats[worst].sat)
        keep = np.arange(len(sats)) != worst
        sats = [m for k, m in enumerate(sats) if keep[k]]
        a, y, sig = a[keep], y[keep], sig[keep]
    q = np.linalg.inv(a.T @ (a / sig[:, None] ** 2))
    return DopplerVelocity(
        time=epoch.time,
        ok=True,
        velocity_mps=x[:3].copy(),
        drift_mps=float(x[3]),
        covariance=q[:3, :3],
        used=tuple(m.sat for m in sats),
        excluded=tuple(excluded),
        residuals_mps={m.sat: float(v[k]) for k, m in enumerate(sats)},
    )
