"""Where every satellite is, seen from every receiver, at one epoch: emission-time states and geometry.

Satellite states come from the project's broadcast-ephemeris code once per epoch, at a reference
emission time seen from the road's origin; each receiver's own emission time differs by
microseconds, over which the state is propagated linearly (error < 1e-9 m). Ranges include the
Sagnac term exactly as coplane.gnss.ephemeris.geometric_range (RTKLIB geodist) does, so a
receiver applying the broadcast models recovers the truth. See docs/simulator.md.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from coplane.gnss.constants import OMEGA_E_GPS, C
from coplane.gnss.ephemeris import sat_state, select_ephemeris, tgd_m
from coplane.gtime import GpsTime
from coplane.recording.model import NavData
from coplane.typing import AnyArray, Mat, Vec

# emission time (s before the epoch) used to decide which satellites are worth computing
_TYPICAL_TRAVEL_S = 0.075


def enu_rotations(lat: Vec, lon: Vec) -> AnyArray:
    """(N, 3, 3) rows E, N, U in ECEF for each receiver (coplane.geo.enu_rotation, vectorised)."""
    sl, cl, so, co = np.sin(lat), np.cos(lat), np.sin(lon), np.cos(lon)
    z = np.zeros_like(lat)
    return np.stack(
        [
            np.stack([-so, co, z], axis=-1),
            np.stack([-sl * co, -sl * so, cl], axis=-1),
            np.stack([cl * co, cl * so, sl], axis=-1),
        ],
        axis=-2,
    )


def sagnac_range(sat: AnyArray, rx: AnyArray) -> tuple[AnyArray, AnyArray]:
    """Vectorised coplane.gnss.ephemeris.geometric_range: (range with Sagnac, |sat - rx|)."""
    d = sat - rx
    geo = np.sqrt(np.einsum("...k,...k->...", d, d))
    return geo + OMEGA_E_GPS * (sat[..., 0] * rx[..., 1] - sat[..., 1] * rx[..., 0]) / C, geo


@dataclass
class SatStates:
    """Per satellite (S) broadcast state at its reference emission time; zeros where not available."""

    avail: AnyArray  # (S,) bool: has an ephemeris and is not well below the origin's horizon
    pos: Mat  # (S, 3) ECEF at the reference emission time
    vel: Mat  # (S, 3)
    clock_s: Vec  # (S,) broadcast clock with relativity
    drift: Vec  # (S,) clock drift s/s
    tgd_m: Vec  # (S,) L1/B1I group delay in metres
    tref: Vec  # (S,) reference emission time minus t (s)


def satellites_at(nav: NavData, sats: list[str], t: GpsTime, origin_ecef: Vec, rot0: Mat) -> SatStates:
    """Broadcast states at the emission time seen from the origin, for satellites near its sky."""
    n_sat = len(sats)
    avail = np.zeros(n_sat, dtype=bool)
    sp = np.zeros((n_sat, 3))
    sv = np.zeros((n_sat, 3))
    clk = np.zeros(n_sat)
    drf = np.zeros(n_sat)
    tgd = np.zeros(n_sat)
    tref = np.zeros(n_sat)
    for i, sat in enumerate(sats):
        eph = select_ephemeris(nav, sat, t + (-_TYPICAL_TRAVEL_S))
        if eph is None:
            continue
        st = sat_state(eph, t + (-_TYPICAL_TRAVEL_S))
        up = rot0[2] @ (st.pos - origin_ecef)
        if up < -0.2 * np.linalg.norm(st.pos - origin_ecef):  # well below the horizon
            continue
        tau = float(np.linalg.norm(st.pos - origin_ecef)) / C
        st = sat_state(eph, t + (-tau))
        avail[i] = True
        sp[i], sv[i], clk[i], drf[i] = st.pos, st.vel, st.clock_s, st.drift_s_per_s
        tgd[i], tref[i] = tgd_m(eph), -tau
    return SatStates(avail, sp, sv, clk, drf, tgd, tref)


@dataclass
class SkyView:
    """Per receiver (N) and satellite (S): the satellite at its true emission time and its direction."""

    spos: AnyArray  # (N, S, 3) satellite ECEF at emission time
    rho: AnyArray  # (N, S) Sagnac-corrected geometric range
    los: AnyArray  # (N, S, 3) unit vector receiver -> satellite
    sclk: AnyArray  # (N, S) satellite clock (s) at emission time
    az: AnyArray  # (N, S) rad, from North through East
    el: AnyArray  # (N, S) rad


def sky_view(sat: SatStates, pos: Mat, rot: AnyArray) -> SkyView:
    """Iterate each receiver's emission time until t - t_tx = rho / c, then its azimuth and elevation."""
    sp, sv = sat.pos, sat.vel
    tau_rx = np.linalg.norm(sp[None, :, :] - pos[:, None, :], axis=-1) / C
    for _ in range(3):
        dtt = -tau_rx - sat.tref[None, :]
        spos = sp[None, :, :] + sv[None, :, :] * dtt[..., None]
        rho, _ = sagnac_range(spos, pos[:, None, :])
        tau_rx = rho / C
    dtt = -tau_rx - sat.tref[None, :]
    spos = sp[None, :, :] + sv[None, :, :] * dtt[..., None]
    rho, geo = sagnac_range(spos, pos[:, None, :])
    los = (spos - pos[:, None, :]) / geo[..., None]
    sclk = sat.clock_s[None, :] + sat.drift[None, :] * dtt
    e_enu = np.einsum("nij,nsj->nsi", rot, los)
    az = np.mod(np.arctan2(e_enu[..., 0], e_enu[..., 1]), 2 * np.pi)
    el = np.arcsin(np.clip(e_enu[..., 2], -1.0, 1.0))
    return SkyView(spos, rho, los, sclk, az, el)


def range_rate(view: SkyView, sat_vel: Mat, pos: Mat, vel: Mat) -> AnyArray:
    """(N, S) time derivative of the Sagnac-corrected range (the geometric part of the Doppler)."""
    los, spos = view.los, view.spos
    return np.einsum("nsk,nsk->ns", los, sat_vel[None, :, :] - vel[:, None, :]) + OMEGA_E_GPS / C * (
        sat_vel[None, :, 0] * pos[:, None, 1]
        + spos[..., 0] * vel[:, None, 1]
        - sat_vel[None, :, 1] * pos[:, None, 0]
        - spos[..., 1] * vel[:, None, 0]
    )
