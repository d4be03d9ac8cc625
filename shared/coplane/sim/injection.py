"""The pseudorange errors of one epoch, per receiver and satellite, from the seeded error processes.

The processes themselves are coplane.sim.errors. What is common to every receiver within a few
km (orbit/clock, ionosphere, troposphere) is evaluated once and mapped to each receiver, so the
base station sees it too and DGNSS removes it; what is private to one antenna (clock, multipath,
NLOS, noise) is drawn per receiver. Each process owns one named random stream. See
docs/simulator.md (measurement model, errors).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from coplane.gnss.atmosphere import GPS_L1_TO_BDS_B1I, iono_delay_m, saastamoinen_m
from coplane.gtime import GpsTime
from coplane.sim.canyon import LOS, NLOS
from coplane.sim.errors import (
    CommonMode,
    GaussMarkov,
    ReceiverClocks,
    code_sigma_m,
    component_rng,
    doppler_sigma_hz,
    klobuchar_obliquity,
    multipath_sigma_m,
    perturbed_iono,
)
from coplane.sim.road import SECTION_KINDS
from coplane.sim.sky import SatStates
from coplane.sim.world import World
from coplane.typing import AnyArray, Mat, Vec

MIN_IONO_ELEVATION_RAD = math.radians(1.0)
MIN_TROPO_SIN_EL = 0.05


@dataclass
class EpochErrors:
    """Injected components at one epoch: metres of pseudorange, (N, S) unless noted."""

    common_m: Vec  # (S,) orbit/clock error shared by every receiver
    iono_m: AnyArray
    iono_broadcast_m: AnyArray  # what the broadcast Klobuchar predicts (zeros unless asked for)
    tropo_m: AnyArray
    tropo_model_m: AnyArray  # what standard Saastamoinen predicts
    multipath_m: AnyArray
    nlos_m: AnyArray
    noise_m: AnyArray
    code_sigma_m: AnyArray
    doppler_noise_hz: AnyArray


class ErrorInjector:
    """Every error process of the scenario, stepped once per epoch in a fixed order."""

    def __init__(self, world: World, seed: int, broadcast_iono: bool = False) -> None:
        sc, dt, sats = world.scenario, world.dt, world.sats
        n_rx, n_sat = world.n_rx, len(sats)
        rx_params = world.rx_params
        self.world = world
        self.broadcast_iono = broadcast_iono  # also evaluate the broadcast model (diagnostics)
        self.is_bds = np.array([s[0] == "C" for s in sats])
        self.common = CommonMode(sats, sc.common_mode, dt, component_rng(seed, "common-mode"))
        iono_rng = component_rng(seed, "iono")
        self.iono_nav, self.iono_scale = perturbed_iono(world.nav, sc.iono, iono_rng)
        self.iono_gm = GaussMarkov((n_sat,), sc.iono.sat_tau_s, dt, iono_rng)
        tropo_rng = component_rng(seed, "tropo")
        self.tropo_scale = 1.0 + sc.tropo.scale_sigma * float(tropo_rng.standard_normal())
        self.tropo_gm = GaussMarkov((1,), sc.tropo.wet_tau_s, dt, tropo_rng)
        self.clocks = ReceiverClocks(
            [p.clock for p in rx_params], len(world.times), dt, component_rng(seed, "clock")
        )
        nlos_rng = component_rng(seed, "nlos")
        # drawn before the jitter process: the C/N0 model (coplane.sim.tracking) takes it from here
        self.nlos_cn0_loss_db = nlos_rng.uniform(*sc.nlos.cn0_loss_db, size=(n_rx, n_sat))
        self.nlos_gm = GaussMarkov((n_rx, n_sat), sc.nlos.jitter_tau_s, dt, nlos_rng)
        mp_rng = component_rng(seed, "multipath")
        self.mp_gms = [
            GaussMarkov((sl.stop - sl.start, n_sat), p.multipath.tau_s, dt, mp_rng) for sl, p in world.groups
        ]
        self.section_mp = np.array(
            [[p.multipath.section_scale.get(k, 1.0) for k in SECTION_KINDS] for p in rx_params]
        )
        self.noise_rng = component_rng(seed, "code-noise")
        self.dop_rng = component_rng(seed, "doppler-noise")

    def inter_system_bias_m(self) -> AnyArray:
        """(N, S) receiver inter-system bias, on BeiDou satellites only."""
        return np.where(self.is_bds[None, :], self.clocks.isb_m[:, None], 0.0)

    def _iono(self, t: GpsTime, sat: SatStates, el: AnyArray, above: AnyArray) -> tuple[AnyArray, AnyArray]:
        """True delay evaluated at the origin with the project's model, mapped to each receiver."""
        w, is_bds = self.world, self.is_bds
        irr = self.iono_gm.step() * w.scenario.iono.sat_sigma_m
        ob_rx = klobuchar_obliquity(el, is_bds[None, :])
        iono = np.zeros(el.shape)
        iono_bc = np.zeros(el.shape)
        o_rel = sat.pos - w.origin_ecef
        o_enu = o_rel @ w.rot0.T / np.linalg.norm(o_rel, axis=1)[:, None]
        az0 = np.mod(np.arctan2(o_enu[:, 0], o_enu[:, 1]), 2 * np.pi)
        el0 = np.arcsin(np.clip(o_enu[:, 2], -1.0, 1.0))
        lat0, lon0 = w.origin_lat, w.origin_lon
        for i in np.flatnonzero(sat.avail & np.any(above, axis=0)).tolist():
            e_o = max(float(el0[i]), MIN_IONO_ELEVATION_RAD)
            sysc = w.sats[i][0]
            true_o = self.iono_scale * iono_delay_m(sysc, t, lat0, lon0, float(az0[i]), e_o, self.iono_nav)
            ob_o = float(klobuchar_obliquity(np.array(e_o), np.array(is_bds[i])))
            true_o += irr[i] * ob_o * (GPS_L1_TO_BDS_B1I if is_bds[i] else 1.0)
            iono[:, i] = true_o * ob_rx[:, i] / ob_o
            if self.broadcast_iono:
                bc_o = iono_delay_m(sysc, t, lat0, lon0, float(az0[i]), e_o, w.nav)
                iono_bc[:, i] = bc_o * ob_rx[:, i] / ob_o
        return iono, iono_bc

    def step(
        self,
        k: int,
        sat: SatStates,
        el: AnyArray,
        above: AnyArray,
        state: AnyArray,
        excess_m: AnyArray,
        cn0: AnyArray,
        llh: Mat,
    ) -> EpochErrors:
        """Advance every process one epoch and return the components for the receivers at `llh`."""
        w = self.world
        sc, m = w.scenario, w.vehicles
        n_rx, n_sat = el.shape
        e_common = self.common.step()
        iono, iono_bc = self._iono(w.times[k], sat, el, above)
        wet = float(self.tropo_gm.step()[0]) * sc.tropo.wet_residual_sigma_m
        zen_trop = np.array([saastamoinen_m(float(la), float(hh), math.pi / 2) for la, _, hh in llh])
        sin_el = np.maximum(np.sin(el), MIN_TROPO_SIN_EL)
        tropo_model = zen_trop[:, None] / sin_el
        tropo = (zen_trop[:, None] * self.tropo_scale + wet) / sin_el
        sec_scale = np.ones(n_rx)
        sec_scale[:m] = self.section_mp[np.arange(m), w.track.section[k]]
        if w.base_ecef is not None:
            sec_scale[m] = self.section_mp[m, SECTION_KINDS.index("open")]
        mp = np.zeros((n_rx, n_sat))
        csig = np.zeros((n_rx, n_sat))
        dsig = np.zeros((n_rx, n_sat))
        for (sl, p), gm in zip(w.groups, self.mp_gms, strict=True):
            mp[sl] = multipath_sigma_m(el[sl], sec_scale[sl, None], p.multipath) * gm.step()
            csig[sl] = code_sigma_m(cn0[sl], self.is_bds[None, :], p.tracking)
            dsig[sl] = doppler_sigma_hz(cn0[sl], p.tracking)
        mp = np.where(state == LOS, mp, 0.0)
        nlos_m = np.where(
            state == NLOS,
            np.maximum(excess_m * (1.0 + sc.nlos.jitter_frac * self.nlos_gm.step()), sc.nlos.floor_m),
            0.0,
        )
        noise = csig * self.noise_rng.standard_normal((n_rx, n_sat))
        dnoise = dsig * self.dop_rng.standard_normal((n_rx, n_sat))
        return EpochErrors(
            common_m=e_common,
            iono_m=iono,
            iono_broadcast_m=iono_bc,
            tropo_m=tropo,
            tropo_model_m=tropo_model,
            multipath_m=mp,
            nlos_m=nlos_m,
            noise_m=noise,
            code_sigma_m=csig,
            doppler_noise_hz=dnoise,
        )
