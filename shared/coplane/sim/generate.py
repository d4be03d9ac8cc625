"""Generate a fleet recording: motion, canyon visibility, GNSS errors, UWB, then the spec's files.

Measurement model per receiver r, satellite s, epoch (true GPS time t, receiver tag t + dtr):

  P = rho + c (dtr - dts) + c TGD + I + T + E_common + MP + NLOS + n
  D = -(rho_dot + c (dtr_dot - dts_dot) + NLOS_dot) / lambda + n_D         (RINEX sign)

* rho is the Sagnac-corrected geometric range (coplane.gnss.ephemeris.geometric_range, which
  equals RTKLIB geodist) from the satellite at its true emission time t_tx to the antenna at t;
  t_tx is iterated until t - t_tx = rho / c, with the satellite state from the project's
  broadcast-ephemeris code (sat_state at a reference emission time, propagated linearly over
  the microseconds that separate receivers: error < 1e-9 m);
* dts is the broadcast satellite clock with relativity (SatState.clock_s) at t_tx; the L1/B1I
  group delay enters as +c TGD because receivers subtract it;
* I is a perturbed Klobuchar (the broadcast model with perturbed coefficients, a scale error
  and per-satellite irregularities), T a scaled Saastamoinen plus a wet residual, E_common the
  orbit/clock error: all three are the same for every receiver within a few km, so the base
  station sees them too and DGNSS removes them;
* MP, NLOS, n and the receiver clock dtr are private to each receiver (errors.py, canyon.py).

A receiver that applies broadcast clocks, TGD, Klobuchar and Saastamoinen therefore sees only
the injected errors. Every random draw comes from a named, seed-derived numpy stream, and no
file contains wall-clock time, so the same seed gives byte-identical files.
"""

from __future__ import annotations

import math
import shutil
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from tqdm import tqdm

from coplane.geo import ecef_to_geodetic, geodetic_to_ecef
from coplane.gnss.atmosphere import GPS_L1_TO_BDS_B1I, iono_delay_m, saastamoinen_m
from coplane.gnss.constants import OMEGA_E_GPS, WAVELENGTH, C, is_bds_geo
from coplane.gnss.ephemeris import sat_state, select_ephemeris, tgd_m
from coplane.gtime import GpsTime
from coplane.recording.csvfiles import write_uwb
from coplane.recording.manifest import write_manifest
from coplane.recording.model import (
    BaseSpec,
    Manifest,
    NavData,
    ObsEpoch,
    ObsHeader,
    SatObservation,
    UwbRange,
    UwbSpec,
    VehicleSpec,
)
from coplane.recording.problems import Problems
from coplane.recording.rinex_nav import read_nav
from coplane.recording.writer import write_obs
from coplane.sim.canyon import BLOCKED, LOS, NLOS, Canyon
from coplane.sim.errors import (
    CommonMode,
    GaussMarkov,
    ReceiverClocks,
    ReceiverParams,
    code_sigma_m,
    component_rng,
    doppler_sigma_hz,
    klobuchar_obliquity,
    multipath_sigma_m,
    perturbed_iono,
)
from coplane.sim.motion import FleetTrack, simulate_motion
from coplane.sim.road import SECTION_KINDS, Road, Sections, enu_to_ecef_curved
from coplane.sim.scenarios import DEFAULT_SCENARIO, Scenario, get_scenario
from coplane.sim.uwb import UwbSimulator

Arr = NDArray[Any]

_DIAG_FIELDS = (
    "el", "cn0", "common_m", "iono_res_m", "tropo_res_m", "multipath_m", "nlos_m", "noise_m", "code_sigma_m",
)  # fmt: skip
NOT_VISIBLE = -1  # diagnostics state for satellites below the mask or without ephemeris
SIGNAL_TYPES = {"G": ("C1C", "D1C", "S1C"), "C": ("C2I", "D2I", "S2I")}
RECEIVER_NAME = "COPLANE SIM"
ANTENNA_NAME = "SIM PATCH"
BASE_ANTENNA_NAME = "SIM CHOKE RING"


@dataclass
class Diagnostics:
    """Per epoch (K), receiver (N = vehicles then base) and satellite (S) injected components.

    state: NOT_VISIBLE / LOS / NLOS / BLOCKED; reported: written to the RINEX file. The error
    components are metres of pseudorange; `iono_res_m` and `tropo_res_m` are what remains after
    the broadcast Klobuchar and standard Saastamoinen models a receiver applies.
    """

    sats: list[str]
    state: Arr
    reported: Arr
    el: Arr
    cn0: Arr
    common_m: Arr
    iono_res_m: Arr
    tropo_res_m: Arr
    multipath_m: Arr
    nlos_m: Arr
    noise_m: Arr
    code_sigma_m: Arr
    clock_bias_s: Arr  # (K, N)
    clock_jumps_s: Arr  # (K, N)


@dataclass
class SimResult:
    """Everything a simulation produced, in memory (write it with `write_recording`)."""

    scenario: Scenario
    seed: int
    times: list[GpsTime]  # true GPS time of each epoch
    vehicle_ids: list[str]
    track: FleetTrack
    road: Road
    sections: Sections
    canyon: Canyon
    nav: NavData
    nav_path: Path
    vehicle_obs: dict[str, list[ObsEpoch]]
    base_obs: list[ObsEpoch]
    base_ecef: Arr | None
    uwb: list[UwbRange]
    diagnostics: Diagnostics | None = None
    uwb_kinds: list[int] = field(default_factory=list)  # 0 LOS, 1 body, 2 building per uwb row


def _enu_rotations(lat: Arr, lon: Arr) -> Arr:
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


def _sagnac_range(sat: Arr, rx: Arr) -> tuple[Arr, Arr]:
    """Vectorised coplane.gnss.ephemeris.geometric_range: (range with Sagnac, |sat - rx|)."""
    d = sat - rx
    geo = np.sqrt(np.einsum("...k,...k->...", d, d))
    return geo + OMEGA_E_GPS * (sat[..., 0] * rx[..., 1] - sat[..., 1] * rx[..., 0]) / C, geo


def _check_window(nav: NavData, sats: list[str], t0: GpsTime, t1: GpsTime) -> None:
    def usable(t: GpsTime) -> int:
        return sum(select_ephemeris(nav, s, t) is not None for s in sats)

    n0, n1 = usable(t0), usable(t1)
    if n1 < n0 or n0 < 8:
        raise ValueError(
            f"time window {t0} .. {t1} leaves the broadcast ephemeris validity "
            f"({n0} satellites usable at the start, {n1} at the end)"
        )


def run_simulation(
    scenario: Scenario | str = DEFAULT_SCENARIO,
    vehicles: int = 4,
    duration_s: float = 600.0,
    seed: int = 0,
    progress: bool = False,
    diagnostics: bool = False,
    on_epoch: Callable[[int, int], None] | None = None,
) -> SimResult:
    """Simulate in memory. `vehicles` >= 1; `duration_s` / interval epochs."""
    sc = get_scenario(scenario) if isinstance(scenario, str) else scenario
    if vehicles < 1:
        raise ValueError("at least one vehicle is needed")
    dt = sc.interval_s
    n_ep = round(duration_s / dt)
    if n_ep < 1:
        raise ValueError(f"duration {duration_s} s is shorter than one epoch")
    problems = Problems()
    nav_path = sc.nav_path()
    nav = read_nav(nav_path, problems)
    if problems.total:
        raise ValueError(f"navigation file {nav_path} has {problems.total} problems")
    sats = sorted(s for s in nav.ephemerides if s[0] in SIGNAL_TYPES)
    t0 = GpsTime.from_calendar(*sc.start)
    times = [t0 + k * dt for k in range(n_ep)]
    _check_window(nav, sats, t0, times[-1])

    rp = sc.road
    road = Road(rp.waypoints_en, rp.corner_radius_m, rp.lanes, rp.lane_width_m, rp.grade_changes)
    sections = Sections(road.length_m, rp.sections)
    canyon = Canyon(road, sections, sc.canyon, component_rng(seed, "canyon"))
    origin = (rp.origin_lat_deg, rp.origin_lon_deg, rp.origin_h_m)
    track = simulate_motion(
        road, sections, sc.motion, vehicles, n_ep, dt, origin, component_rng(seed, "motion")
    )
    origin_ecef = geodetic_to_ecef(
        math.radians(rp.origin_lat_deg), math.radians(rp.origin_lon_deg), rp.origin_h_m
    )

    base_ecef: Arr | None = None
    if sc.base is not None:
        b = sc.base
        base_ecef = np.round(
            enu_to_ecef_curved(np.array([b.east_m, b.north_m, b.height_above_origin_m]), *origin), 4
        )
    m = vehicles
    n_rx = m + (1 if base_ecef is not None else 0)
    rx_params: list[ReceiverParams] = [sc.vehicle_receiver] * m + (
        [sc.base_receiver] if base_ecef is not None else []
    )
    n_sat = len(sats)
    is_bds = np.array([s[0] == "C" for s in sats])
    geo_sat = np.array([is_bds_geo(s) for s in sats])
    lam = np.array([WAVELENGTH[s[0]] for s in sats])

    # --- error processes (one named stream each) ---
    common = CommonMode(sats, sc.common_mode, dt, component_rng(seed, "common-mode"))
    iono_rng = component_rng(seed, "iono")
    iono_nav, iono_scale = perturbed_iono(nav, sc.iono, iono_rng)
    iono_gm = GaussMarkov((n_sat,), sc.iono.sat_tau_s, dt, iono_rng)
    tropo_rng = component_rng(seed, "tropo")
    tropo_scale = 1.0 + sc.tropo.scale_sigma * float(tropo_rng.standard_normal())
    tropo_gm = GaussMarkov((1,), sc.tropo.wet_tau_s, dt, tropo_rng)
    clocks = ReceiverClocks([p.clock for p in rx_params], n_ep, dt, component_rng(seed, "clock"))
    # receivers come in two groups with their own parameters: vehicles (rows :m) and the base
    groups: list[tuple[slice, ReceiverParams]] = [(slice(0, m), sc.vehicle_receiver)]
    if base_ecef is not None:
        groups.append((slice(m, m + 1), sc.base_receiver))
    cn0_rng = component_rng(seed, "cn0")
    zen = np.array([p.cn0.zenith_dbhz for p in rx_params]) + np.array(
        [p.zenith_spread_db for p in rx_params]
    ) * cn0_rng.standard_normal(n_rx)
    drop = np.array([p.cn0.horizon_drop_db for p in rx_params])[:, None]
    sat_off = np.array([p.cn0.sat_sigma_db for p in rx_params])[:, None] * cn0_rng.standard_normal(
        (n_rx, n_sat)
    )
    sat_off += np.array([p.cn0.bds_geo_offset_db for p in rx_params])[:, None] * geo_sat[None, :]
    cn0_gm = GaussMarkov((n_rx, n_sat), sc.vehicle_receiver.cn0.noise_tau_s, dt, cn0_rng)
    cn0_noise = np.array([p.cn0.noise_sigma_db for p in rx_params])[:, None]
    threshold = np.array([p.cn0.track_threshold_dbhz for p in rx_params])[:, None]
    nlos_rng = component_rng(seed, "nlos")
    nlos_loss = nlos_rng.uniform(*sc.nlos.cn0_loss_db, size=(n_rx, n_sat))
    nlos_gm = GaussMarkov((n_rx, n_sat), sc.nlos.jitter_tau_s, dt, nlos_rng)
    mp_rng = component_rng(seed, "multipath")
    mp_gms = [GaussMarkov((sl.stop - sl.start, n_sat), p.multipath.tau_s, dt, mp_rng) for sl, p in groups]
    section_mp = np.array([[p.multipath.section_scale.get(k, 1.0) for k in SECTION_KINDS] for p in rx_params])
    noise_rng = component_rng(seed, "code-noise")
    dop_rng = component_rng(seed, "doppler-noise")
    mask = np.array([math.radians(p.tracking.elevation_mask_deg) for p in rx_params])[:, None]
    reacq = np.array([p.tracking.reacquire_epochs for p in rx_params])[:, None]
    lock = np.broadcast_to(reacq - 1, (n_rx, n_sat)).copy()
    uwb_sim = None
    if sc.uwb is not None and m > 1:
        uwb_sim = UwbSimulator(m, sc.uwb, canyon.footprint_grid(), component_rng(seed, "uwb"))

    diag: Diagnostics | None = None
    if diagnostics:
        shp = (n_ep, n_rx, n_sat)
        diag = Diagnostics(
            sats=sats,
            state=np.full(shp, NOT_VISIBLE, dtype=np.int8),
            reported=np.zeros(shp, dtype=bool),
            **{k: np.full(shp, np.nan) for k in _DIAG_FIELDS},
            clock_bias_s=clocks.bias,
            clock_jumps_s=clocks.jumps,
        )

    ids = track.ids
    vehicle_obs: dict[str, list[ObsEpoch]] = {vid: [] for vid in ids}
    base_obs: list[ObsEpoch] = []
    uwb_rows: list[UwbRange] = []
    uwb_kinds: list[int] = []
    lat0, lon0 = math.radians(rp.origin_lat_deg), math.radians(rp.origin_lon_deg)
    rot0 = _enu_rotations(np.array([lat0]), np.array([lon0]))[0]
    delta = 0.1  # s, for the NLOS extra-path rate

    for k in tqdm(range(n_ep), desc="simulate", unit="epoch", disable=not progress):
        t = times[k]
        # receivers
        pos = track.ecef[k]
        vel = track.vel_ecef[k]
        if base_ecef is not None:
            pos = np.vstack([pos, base_ecef[None, :]])
            vel = np.vstack([vel, np.zeros((1, 3))])
        llh = ecef_to_geodetic(pos)
        rot = _enu_rotations(llh[:, 0], llh[:, 1])

        # satellites at a reference emission time (seen from the origin), then per receiver
        avail = np.zeros(n_sat, dtype=bool)
        sp = np.zeros((n_sat, 3))
        sv = np.zeros((n_sat, 3))
        clk = np.zeros(n_sat)
        drf = np.zeros(n_sat)
        tgd = np.zeros(n_sat)
        tref = np.zeros(n_sat)  # reference emission time minus t (s)
        for i, sat in enumerate(sats):
            eph = select_ephemeris(nav, sat, t + (-0.075))
            if eph is None:
                continue
            st = sat_state(eph, t + (-0.075))
            up = rot0[2] @ (st.pos - origin_ecef)
            if up < -0.2 * np.linalg.norm(st.pos - origin_ecef):  # well below the horizon
                continue
            tau = float(np.linalg.norm(st.pos - origin_ecef)) / C
            st = sat_state(eph, t + (-tau))
            avail[i] = True
            sp[i], sv[i], clk[i], drf[i] = st.pos, st.vel, st.clock_s, st.drift_s_per_s
            tgd[i], tref[i] = tgd_m(eph), -tau
        tau_rx = np.linalg.norm(sp[None, :, :] - pos[:, None, :], axis=-1) / C
        for _ in range(3):
            dtt = -tau_rx - tref[None, :]
            spos = sp[None, :, :] + sv[None, :, :] * dtt[..., None]
            rho, _ = _sagnac_range(spos, pos[:, None, :])
            tau_rx = rho / C
        dtt = -tau_rx - tref[None, :]
        spos = sp[None, :, :] + sv[None, :, :] * dtt[..., None]
        rho, geo = _sagnac_range(spos, pos[:, None, :])
        los = (spos - pos[:, None, :]) / geo[..., None]
        sclk = clk[None, :] + drf[None, :] * dtt
        e_enu = np.einsum("nij,nsj->nsi", rot, los)
        az = np.mod(np.arctan2(e_enu[..., 0], e_enu[..., 1]), 2 * np.pi)
        el = np.arcsin(np.clip(e_enu[..., 2], -1.0, 1.0))
        above = avail[None, :] & (el > mask)

        # canyon (vehicles) -- the base is in open sky
        state = np.full((n_rx, n_sat), BLOCKED, dtype=np.int8)
        state[above] = LOS
        excess = np.zeros((n_rx, n_sat))
        excess_rate = np.zeros((n_rx, n_sat))
        sec_v = track.section[k]
        vi, si = np.nonzero(above[:m])
        if len(vi):
            s_v, y_v, h_v = track.s[k][vi], track.y[k][vi], track.antenna_height_m[vi]
            hd = track.heading[k][vi]
            vis = canyon.visibility(s_v, y_v, h_v, hd, az[vi, si][:, None], el[vi, si][:, None])
            st_v = vis.state[:, 0]
            state[vi, si] = st_v
            ex = vis.excess_m[:, 0]
            excess[vi, si] = ex
            nl = st_v == NLOS
            if np.any(nl):
                # extra path a moment later with the reflecting facade frozen -> its time derivative
                a, b = vi[nl], si[nl]
                rel = spos[a, b] + sv[b] * delta - (pos[a] + vel[a] * delta)
                e2 = np.einsum("pij,pj->pi", rot[a], rel / np.linalg.norm(rel, axis=1)[:, None])
                az2 = np.arctan2(e2[:, 0], e2[:, 1])
                el2 = np.arcsin(np.clip(e2[:, 2], -1.0, 1.0))
                s2 = track.s[k][a] + track.s_rate[k][a] * delta
                y2 = track.y[k][a] + track.y_rate[k][a] * delta
                _, hd2, _ = road.frame(s2)
                ref = vis.reflect_setback_m[nl, 0]
                sg = vis.sign[nl, 0]
                ex1 = canyon.reflection_extra(ref, sg, track.y[k][a], hd[nl], az[a, b], el[a, b])
                ex2 = canyon.reflection_extra(ref, sg, y2, hd2, az2, el2)
                excess_rate[a, b] = np.clip((ex2 - ex1) / delta, -30.0, 30.0)

        # C/N0 and tracking
        cn0 = zen[:, None] - drop * (1.0 - np.sin(np.maximum(el, 0.0))) ** 2 + sat_off
        cn0 = cn0 + cn0_noise * cn0_gm.step()
        cn0 = np.where(state == NLOS, cn0 - nlos_loss, cn0)
        cn0 = np.clip(cn0, 0.0, 60.0)
        trackable = above & (state != BLOCKED) & (cn0 >= threshold)
        lock = np.where(trackable, lock + 1, 0)
        reported = trackable & (lock >= reacq)

        # errors
        e_common = common.step()
        irr = iono_gm.step() * sc.iono.sat_sigma_m
        wet = float(tropo_gm.step()[0]) * sc.tropo.wet_residual_sigma_m
        ob_rx = klobuchar_obliquity(el, is_bds[None, :])
        iono = np.zeros((n_rx, n_sat))
        iono_bc = np.zeros((n_rx, n_sat))
        o_rel = sp - origin_ecef
        o_enu = o_rel @ rot0.T / np.linalg.norm(o_rel, axis=1)[:, None]
        az0 = np.mod(np.arctan2(o_enu[:, 0], o_enu[:, 1]), 2 * np.pi)
        el0 = np.arcsin(np.clip(o_enu[:, 2], -1.0, 1.0))
        # true delay evaluated at the origin with the project's model, mapped to each receiver
        for i in np.flatnonzero(avail & np.any(above, axis=0)).tolist():
            e_o = max(float(el0[i]), math.radians(1.0))
            sysc = sats[i][0]
            true_o = iono_scale * iono_delay_m(sysc, t, lat0, lon0, float(az0[i]), e_o, iono_nav)
            ob_o = float(klobuchar_obliquity(np.array(e_o), np.array(is_bds[i])))
            true_o += irr[i] * ob_o * (GPS_L1_TO_BDS_B1I if is_bds[i] else 1.0)
            iono[:, i] = true_o * ob_rx[:, i] / ob_o
            if diag is not None:
                bc_o = iono_delay_m(sysc, t, lat0, lon0, float(az0[i]), e_o, nav)
                iono_bc[:, i] = bc_o * ob_rx[:, i] / ob_o
        zen_trop = np.array([saastamoinen_m(float(la), float(hh), math.pi / 2) for la, _, hh in llh])
        sin_el = np.maximum(np.sin(el), 0.05)
        tropo_model = zen_trop[:, None] / sin_el
        tropo = (zen_trop[:, None] * tropo_scale + wet) / sin_el
        sec_scale = np.ones(n_rx)
        sec_scale[:m] = section_mp[np.arange(m), sec_v]
        if base_ecef is not None:
            sec_scale[m] = section_mp[m, SECTION_KINDS.index("open")]
        mp = np.zeros((n_rx, n_sat))
        csig = np.zeros((n_rx, n_sat))
        dsig = np.zeros((n_rx, n_sat))
        for (sl, p), gm in zip(groups, mp_gms, strict=True):
            mp[sl] = multipath_sigma_m(el[sl], sec_scale[sl, None], p.multipath) * gm.step()
            csig[sl] = code_sigma_m(cn0[sl], is_bds[None, :], p.tracking)
            dsig[sl] = doppler_sigma_hz(cn0[sl], p.tracking)
        mp = np.where(state == LOS, mp, 0.0)
        nlos_m = np.where(
            state == NLOS,
            np.maximum(excess * (1.0 + sc.nlos.jitter_frac * nlos_gm.step()), sc.nlos.floor_m),
            0.0,
        )
        noise = csig * noise_rng.standard_normal((n_rx, n_sat))
        dnoise = dsig * dop_rng.standard_normal((n_rx, n_sat))

        bias = clocks.bias[k]
        drift = clocks.drift[k]
        isb = np.where(is_bds[None, :], clocks.isb_m[:, None], 0.0)
        pr = (
            rho + C * bias[:, None] + isb - C * sclk + tgd[None, :]
            + iono + tropo + e_common[None, :] + mp + nlos_m + noise
        )  # fmt: skip
        rdot = np.einsum("nsk,nsk->ns", los, sv[None, :, :] - vel[:, None, :]) + OMEGA_E_GPS / C * (
            sv[None, :, 0] * pos[:, None, 1]
            + spos[..., 0] * vel[:, None, 1]
            - sv[None, :, 1] * pos[:, None, 0]
            - spos[..., 1] * vel[:, None, 0]
        )
        dop = -(rdot + C * (drift[:, None] - drf[None, :]) + excess_rate) / lam[None, :] + dnoise

        for r in range(n_rx):
            idx = np.flatnonzero(reported[r])
            obs = tuple(
                SatObservation(sats[i], float(pr[r, i]), float(dop[r, i]), float(cn0[r, i])) for i in idx
            )
            ep = ObsEpoch(GpsTime(t.week, t.tow + float(bias[r])), obs)
            if r < m:
                vehicle_obs[ids[r]].append(ep)
            else:
                base_obs.append(ep)

        if uwb_sim is not None:
            u = uwb_sim.step(track.ecef[k], track.enu[k][:, :2])
            for a_i, b_i, rg, kd in zip(u.i, u.j, u.range_m, u.nlos, strict=True):
                uwb_rows.append(UwbRange(t, ids[int(a_i)], ids[int(b_i)], round(float(rg), 4)))
                uwb_kinds.append(int(kd))

        if diag is not None:
            diag.state[k] = np.where(above, state, NOT_VISIBLE)
            diag.reported[k] = reported
            diag.el[k] = el
            diag.cn0[k] = cn0
            diag.common_m[k] = e_common[None, :]
            diag.iono_res_m[k] = iono - iono_bc
            diag.tropo_res_m[k] = tropo - tropo_model
            diag.multipath_m[k] = mp
            diag.nlos_m[k] = nlos_m
            diag.noise_m[k] = noise
            diag.code_sigma_m[k] = csig
        if on_epoch is not None:
            on_epoch(k + 1, n_ep)

    return SimResult(
        scenario=sc,
        seed=seed,
        times=times,
        vehicle_ids=ids,
        track=track,
        road=road,
        sections=sections,
        canyon=canyon,
        nav=nav,
        nav_path=nav_path,
        vehicle_obs=vehicle_obs,
        base_obs=base_obs,
        base_ecef=base_ecef,
        uwb=uwb_rows,
        diagnostics=diag,
        uwb_kinds=uwb_kinds,
    )


# --- writing ----------------------------------------------------------------------------------

TRUTH_HEADER = "gps_week,tow_s,x_m,y_m,z_m,vx_mps,vy_mps,vz_mps,section,lane"


def _tow(tow: float) -> str:
    return f"{tow:.3f}"


def write_truth_csv(path: Path, times: list[GpsTime], track: FleetTrack, v: int) -> None:
    """truth/<id>.csv with the spec's columns plus velocity, section kind and lane (extra columns)."""
    names = track.section_names()
    lines = [TRUTH_HEADER]
    for k, t in enumerate(times):
        x, y, z = track.ecef[k, v]
        vx, vy, vz = track.vel_ecef[k, v]
        lines.append(
            f"{t.week},{_tow(t.tow)},{x:.4f},{y:.4f},{z:.4f},{vx:.4f},{vy:.4f},{vz:.4f},"
            f"{names[k, v]},{int(track.lane[k, v])}"
        )
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n", encoding="ascii", newline="\n")


def write_recording(result: SimResult, out_dir: str | Path) -> Path:
    """Write the fleet recording (fleet.toml, nav/, base/, vehicles/, uwb.csv, truth/)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    sc = result.scenario
    nav_rel = Path("nav") / "brdc.rnx"
    (out / "nav").mkdir(exist_ok=True)
    shutil.copyfile(result.nav_path, out / nav_rel)  # the real file, byte for byte

    obs_types: dict[str, tuple[str, ...]] = dict(SIGNAL_TYPES)
    specs = []
    for v, vid in enumerate(result.vehicle_ids):
        first = result.track.ecef[0, v]
        header = ObsHeader(
            version=3.04,
            marker_name=vid,
            receiver=RECEIVER_NAME,
            antenna=ANTENNA_NAME,
            approx_position_ecef_m=(
                round(float(first[0]), 1),
                round(float(first[1]), 1),
                round(float(first[2]), 1),
            ),
            obs_types=obs_types,
            interval_s=sc.interval_s,
        )
        obs_path = out / "vehicles" / f"{vid}.obs"
        write_obs(obs_path, header, result.vehicle_obs[vid])
        truth_path = out / "truth" / f"{vid}.csv"
        write_truth_csv(truth_path, result.times, result.track, v)
        specs.append(VehicleSpec(vid, obs_path, float(result.track.antenna_height_m[v]), truth_path))

    base_spec = None
    if result.base_ecef is not None and sc.base is not None:
        bpos = tuple(float(x) for x in result.base_ecef)
        header = ObsHeader(
            version=3.04,
            marker_name=sc.base.name,
            receiver=RECEIVER_NAME,
            antenna=BASE_ANTENNA_NAME,
            approx_position_ecef_m=(bpos[0], bpos[1], bpos[2]),
            obs_types=obs_types,
            interval_s=sc.interval_s,
        )
        base_path = out / "base" / f"{sc.base.name}.obs"
        write_obs(base_path, header, result.base_obs)
        base_spec = BaseSpec(base_path, (bpos[0], bpos[1], bpos[2]))

    uwb_spec = None
    if sc.uwb is not None and len(result.vehicle_ids) > 1:
        uwb_path = out / "uwb.csv"
        write_uwb(uwb_path, result.uwb)
        uwb_spec = UwbSpec(uwb_path, sc.uwb.sigma_m, sc.uwb.max_range_m)

    manifest = Manifest(
        root=out,
        name=f"sim {sc.name} seed {result.seed}: {len(result.vehicle_ids)} vehicles, {len(result.times)} epochs",
        interval_s=sc.interval_s,
        nav_files=(out / nav_rel,),
        vehicles=tuple(specs),
        base=base_spec,
        uwb=uwb_spec,
    )
    write_manifest(manifest)
    return out


def simulate(
    scenario: Scenario | str = DEFAULT_SCENARIO,
    out_dir: str | Path = "sim-recording",
    vehicles: int = 4,
    duration_s: float = 600.0,
    seed: int = 0,
    progress: bool = False,
) -> Path:
    """Simulate a fleet and write the recording; returns its directory."""
    result = run_simulation(scenario, vehicles, duration_s, seed, progress)
    return write_recording(result, out_dir)


# --- the bundled default recording --------------------------------------------------------------


@dataclass(frozen=True)
class DefaultRecording:
    """How the bundled default recording is made (README and `coplane fleet` replay it)."""

    scenario: str = DEFAULT_SCENARIO
    vehicles: int = 4
    duration_s: float = 600.0
    seed: int = 0


DEFAULT_RECORDING = DefaultRecording()


def bundled_default_path() -> Path:
    """Where the committed default recording lives inside the package (coplane/data/recordings)."""
    from coplane.sim.scenarios import bundled_nav_path

    return bundled_nav_path().parent.parent / "recordings" / "default"


def ensure_default_recording(cache_dir: str | Path | None = None) -> Path:
    """The default recording (urban-loop, 4 vehicles, 600 s, seed 0), ready to replay.

    The package ships it (coplane/data/recordings/default, 4.3 MB; tests check it is exactly what
    the simulator produces). If that copy is missing (e.g. a slimmed install), it is generated
    once, deterministically, into `cache_dir` (default $COPLANE_CACHE_DIR or ~/.cache/coplane)
    and reused from there.
    """
    import os
    import tempfile

    bundled = bundled_default_path()
    if (bundled / "fleet.toml").is_file():
        return bundled
    root = Path(cache_dir or os.environ.get("COPLANE_CACHE_DIR") or Path.home() / ".cache" / "coplane")
    target = root / "recordings" / "default"
    if (target / "fleet.toml").is_file():
        return target
    root.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix="default-", dir=root))
    p = DEFAULT_RECORDING
    simulate(p.scenario, tmp, p.vehicles, p.duration_s, p.seed)
    target.parent.mkdir(parents=True, exist_ok=True)
    try:
        tmp.rename(target)  # atomic: a concurrent first use never sees a half-written recording
    except OSError:
        shutil.rmtree(tmp, ignore_errors=True)
        if not (target / "fleet.toml").is_file():
            raise
    return target
