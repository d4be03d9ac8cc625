"""Broadcast-ephemeris satellite states (GPS LNAV, BeiDou D1/D2) and the range geometry around them.

The maths follows IS-GPS-200 Table 20-IV and the BDS-SIS-ICD (B1I) section 5.2.4.12, and the
conventions follow RTKLIB 2.4.3 b34 (`satposs`/`eph2pos`/`geodist`) so our SPP can be checked
against RTKLIB number for number (tests/gnss/test_ephemeris.py: < 1 mm, < 1 ps; docs/gnss-models.md).

Differences from RTKLIB, all deliberate:
* velocity and clock drift are the analytic time derivatives of the position/clock model, where
  RTKLIB takes a 1 ms forward difference (its truncation error is ~0.3 mm/s);
* `select_ephemeris` skips unhealthy records (RTKLIB selects, then drops the satellite);
* `satellite_states` selects the ephemeris at the emission time, RTKLIB at the receiver time tag
  (identical except when the epoch falls exactly halfway between two toe).

Everything here is scalar `math` on Python floats: SPP calls `sat_state` about 20 times per
vehicle and epoch, and numpy's per-call overhead on 3-vectors would dominate. `satellite_states`
evaluates each orbit once per 0.1 ms slot of emission time and moves that state to each receiver's
exact emission time (see `slotted_state`): a fleet's receivers and its DGNSS base all see a
satellite within microseconds of each other, so in one process they share the orbit evaluation.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from coplane.gnss.constants import MU_BDS, MU_GPS, OMEGA_E_BDS, OMEGA_E_GPS, C, is_bds_geo
from coplane.gtime import SECONDS_PER_WEEK, GpsTime, gpst_to_bdt
from coplane.recording.broadcast import URA_TABLE_M  # RTKLIB quantises the variance by it
from coplane.recording.model import Ephemeris, NavData

# RTKLIB MAXDTOE / MAXDTOE_CMP (s). RTKLIB's seleph accepts |t - toe| <= MAXDTOE + 1 s; we do too.
MAX_DTOE_S: dict[str, float] = {"G": 7200.0, "C": 21600.0}
_DTOE_MARGIN_S = 1.0

# Constants per system: gravitational parameter and Earth rotation rate of its reference frame.
_ORBIT_CONSTANTS: dict[str, tuple[float, float]] = {
    "G": (MU_GPS, OMEGA_E_GPS),
    "C": (MU_BDS, OMEGA_E_BDS),
}

# BeiDou GEO: the orbit is given in a frame tilted by -5 deg about X (BDS-SIS-ICD 5.2.4.12).
_SIN_M5 = math.sin(math.radians(-5.0))
_COS_M5 = math.cos(math.radians(-5.0))

_KEPLER_TOL = 1e-13  # RTKLIB RTOL_KEPLER
_KEPLER_MAX_ITER = 30


@dataclass(frozen=True)
class SatState:
    """A satellite at signal emission time, in the ECEF frame of that instant.

    `clock_s` is the satellite clock offset including the relativistic correction but excluding
    the group delay (apply `tgd_m` to the code instead). `variance_m2` is the URA-based variance
    of the orbit+clock error, as RTKLIB's `var_uraeph`.
    """

    sat: str
    pos: np.ndarray
    vel: np.ndarray
    clock_s: float
    drift_s_per_s: float
    eph: Ephemeris
    variance_m2: float


def ura_variance_m2(sva_m: float) -> float:
    """Ephemeris variance from the broadcast accuracy (metres), quantised as RTKLIB does."""
    for value in URA_TABLE_M:
        if value >= sva_m:
            return value * value
    return URA_TABLE_M[-1] ** 2


# `_select`'s last choice per ephemeris list: (the list, its length, span start, span end, choice)
_selections: dict[int, tuple[list[Ephemeris], int, float, float, Ephemeris]] = {}
_MAX_SELECTIONS = 4096  # cleared when full: one entry per satellite is all a process needs


def select_ephemeris(nav: NavData, sat: str, t: GpsTime) -> Ephemeris | None:
    """The healthy ephemeris with toe closest to `t`, or None.

    RTKLIB's `seleph` rule: |t - toe| must be within MAXDTOE + 1 s (7201 s GPS, 21601 s BeiDou);
    on a tie the later record wins. Unlike RTKLIB, records with `health != 0` are skipped here,
    so an unhealthy satellite yields None (RTKLIB would select it and then exclude the
    satellite in `satexclude`; the result for SPP is the same). Systems other than GPS and
    BeiDou yield None. Relies on each list being sorted by toe, as `NavData.add` keeps it.
    """
    return _select(nav, sat, t.week, t.tow)


def _select(nav: NavData, sat: str, week: int, tow: float) -> Ephemeris | None:
    """`select_ephemeris` at second `tow` of GPS week `week` (`tow` may run outside [0, 604800)).

    Each satellite's last selection is kept with the span of time over which it stays the
    selection (`_span`): an epoch asks twice per satellite and the next epoch again, and
    scanning the records each time was a tenth of an epoch's cost.
    """
    ephs = nav.ephemerides.get(sat)
    if not ephs or sat[0] not in MAX_DTOE_S:
        return None
    t = week * SECONDS_PER_WEEK + tow
    hit = _selections.get(id(ephs))
    # the list itself is held, so its id is not reused; `NavData.add` only inserts, so its
    # length tells whether it changed
    if hit is not None and hit[0] is ephs and hit[1] == len(ephs) and hit[2] <= t <= hit[3]:
        return hit[4]
    limit = MAX_DTOE_S[sat[0]] + _DTOE_MARGIN_S
    best: Ephemeris | None = None
    best_dt = math.inf
    for e in ephs:  # sorted by toe
        signed = (e.toe.week - week) * SECONDS_PER_WEEK + (e.toe.tow - tow)
        if signed > limit:
            break
        if e.health != 0:
            continue
        dt = abs(signed)
        if dt <= limit and dt <= best_dt:
            best, best_dt = e, dt
    if best is not None:
        lo, hi = _span(ephs, best, limit)
        if lo <= t <= hi:
            if len(_selections) >= _MAX_SELECTIONS:
                _selections.clear()
            _selections[id(ephs)] = (ephs, len(ephs), lo, hi, best)
    return best


def _span(ephs: list[Ephemeris], best: Ephemeris, limit: float) -> tuple[float, float]:
    """GPS seconds over which `best` is `_select`'s choice among `ephs`, a millisecond inside
    the exact bounds (halfway to the healthy neighbours' toe, and `limit` from its own), so
    rounding near a bound always goes to a scan."""

    def toe_s(e: Ephemeris) -> float:
        return e.toe.week * SECONDS_PER_WEEK + e.toe.tow

    healthy = [e for e in ephs if e.health == 0]
    j = next(i for i, e in enumerate(healthy) if e is best)
    t0 = toe_s(best)
    lo, hi = t0 - limit, t0 + limit
    if j > 0:
        lo = max(lo, 0.5 * (toe_s(healthy[j - 1]) + t0))
    if j + 1 < len(healthy):
        hi = min(hi, 0.5 * (t0 + toe_s(healthy[j + 1])))
    return lo + 1e-3, hi - 1e-3


def sat_clock_s(eph: Ephemeris, t: GpsTime) -> float:
    """Clock polynomial at satellite-clock time `t`, without relativity or TGD (RTKLIB eph2clk).

    `t` is the satellite's own (uncorrected) time, so dt = poly(t - dt - toc) is solved by two
    fixed-point steps (converged to ~af1^3*dt); the result feeds the emission-time computation.
    """
    return _clock(eph, t.week, t.tow)


def _clock(eph: Ephemeris, week: int, tow: float) -> float:
    """`sat_clock_s` at second `tow` of GPS week `week`."""
    ts = (week - eph.toc.week) * SECONDS_PER_WEEK + (tow - eph.toc.tow)
    tk = ts
    for _ in range(2):
        tk = ts - (eph.af0 + eph.af1 * tk + eph.af2 * tk * tk)
    return eph.af0 + eph.af1 * tk + eph.af2 * tk * tk


def sat_state(eph: Ephemeris, t: GpsTime) -> SatState:
    """Position, velocity, clock and drift of `eph.sat` at GPST `t` (true emission time).

    Velocity and drift are the analytic derivatives of the same model (not RTKLIB's 1 ms
    forward difference), so they are exactly consistent with position and clock.
    """
    try:
        mu, omge = _ORBIT_CONSTANTS[eph.sat[0]]
    except KeyError:
        raise ValueError(f"{eph.sat}: only GPS and BeiDou ephemerides are supported") from None
    tk = (t.week - eph.toe.week) * SECONDS_PER_WEEK + (t.tow - eph.toe.tow)
    # toe as seconds of the system's own week: the Omega reference uses the broadcast value
    toes = gpst_to_bdt(eph.toe)[1] if eph.sat[0] == "C" else eph.toe.tow

    a = eph.sqrt_a * eph.sqrt_a
    ecc = eph.e
    n = math.sqrt(mu / (a * a * a)) + eph.delta_n
    m = eph.m0 + n * tk
    ea, ek, it = m, 0.0, 0
    while abs(ea - ek) > _KEPLER_TOL and it < _KEPLER_MAX_ITER:
        ek = ea
        ea -= (ea - ecc * math.sin(ea) - m) / (1.0 - ecc * math.cos(ea))
        it += 1
    sin_e, cos_e = math.sin(ea), math.cos(ea)
    one_m_ecos = 1.0 - ecc * cos_e
    e_dot = n / one_m_ecos
    sq = math.sqrt(1.0 - ecc * ecc)

    phi = math.atan2(sq * sin_e, cos_e - ecc) + eph.omega
    phi_dot = sq * e_dot / one_m_ecos
    s2, c2 = math.sin(2.0 * phi), math.cos(2.0 * phi)
    u = phi + eph.cus * s2 + eph.cuc * c2
    r = a * one_m_ecos + eph.crs * s2 + eph.crc * c2
    inc = eph.i0 + eph.idot * tk + eph.cis * s2 + eph.cic * c2
    u_dot = phi_dot * (1.0 + 2.0 * (eph.cus * c2 - eph.cuc * s2))
    r_dot = a * ecc * sin_e * e_dot + 2.0 * phi_dot * (eph.crs * c2 - eph.crc * s2)
    i_dot = eph.idot + 2.0 * phi_dot * (eph.cis * c2 - eph.cic * s2)

    su, cu = math.sin(u), math.cos(u)
    x, y = r * cu, r * su
    x_dot = r_dot * cu - r * su * u_dot
    y_dot = r_dot * su + r * cu * u_dot
    si, ci = math.sin(inc), math.cos(inc)

    geo = is_bds_geo(eph.sat)
    if geo:  # inertial-like node longitude; Earth rotation applied after the -5 deg tilt
        om = eph.omega0 + eph.omega_dot * tk - omge * toes
        om_dot = eph.omega_dot
    else:
        om = eph.omega0 + (eph.omega_dot - omge) * tk - omge * toes
        om_dot = eph.omega_dot - omge
    so, co = math.sin(om), math.cos(om)
    px = x * co - y * ci * so
    py = x * so + y * ci * co
    pz = y * si
    vx = x_dot * co - y_dot * ci * so + y * si * so * i_dot - py * om_dot
    vy = x_dot * so + y_dot * ci * co - y * si * co * i_dot + px * om_dot
    vz = y_dot * si + y * ci * i_dot

    if geo:
        # tilt by -5 deg about X, then rotate by omge*tk about Z (BDS-SIS-ICD 5.2.4.12)
        gy = py * _COS_M5 + pz * _SIN_M5
        gz = -py * _SIN_M5 + pz * _COS_M5
        gvy = vy * _COS_M5 + vz * _SIN_M5
        gvz = -vy * _SIN_M5 + vz * _COS_M5
        ang = omge * tk
        sa, ca = math.sin(ang), math.cos(ang)
        px, py, pz = ca * px + sa * gy, -sa * px + ca * gy, gz
        vx, vy, vz = ca * vx + sa * gvy + omge * py, -sa * vx + ca * gvy - omge * px, gvz

    tc = (t.week - eph.toc.week) * SECONDS_PER_WEEK + (t.tow - eph.toc.tow)
    rel = -2.0 * math.sqrt(mu * a) * ecc / (C * C)  # times sinE: relativistic clock term
    clock = eph.af0 + eph.af1 * tc + eph.af2 * tc * tc + rel * sin_e
    drift = eph.af1 + 2.0 * eph.af2 * tc + rel * cos_e * e_dot

    return SatState(
        sat=eph.sat,
        pos=np.array([px, py, pz]),
        vel=np.array([vx, vy, vz]),
        clock_s=clock,
        drift_s_per_s=drift,
        eph=eph,
        variance_m2=ura_variance_m2(eph.sva),
    )


# Emission-time slot for `slotted_state`. Within half a slot of its centre a state moved along its
# velocity is off by |a| dt^2 / 2 < 1 m/s^2 * (5e-5 s)^2 / 2 ~ 1e-9 m in position and
# |a| dt < 5e-5 m/s in velocity: far below what RTKLIB agreement (2e-7 m) and SPP need.
STATE_SLOT_S = 1e-4
# The slot cache is cleared when it reaches this size: it only has to hold one epoch's satellites.
_MAX_SLOTS = 2048
_slots: dict[tuple[int, int, int], SatState] = {}


def slotted_state(eph: Ephemeris, t: GpsTime) -> SatState:
    """`sat_state(eph, t)` via the state at the centre of t's 0.1 ms slot, moved by the velocity.

    The slot state is a pure function of (ephemeris, slot), so the result does not depend on
    which receiver asked first or on the cache at all: an agent process alone and the in-process
    evaluator with the whole fleet get the same bits. Cache keys hold `id(eph)`; the cached state
    keeps `eph` alive, so an id cannot be reused by another ephemeris while its entry exists.
    """
    k = round(t.tow / STATE_SLOT_S)
    return _moved([_slot_state(eph, t.week, k)], [t.tow - k * STATE_SLOT_S])[0]


def _moved(refs: list[SatState], dts: list[float]) -> list[SatState]:
    """Each slot state moved along its velocity and clock drift by its `dts` seconds, in one numpy
    operation for the whole list (the same IEEE operations element by element as one at a time)."""
    dt = np.array(dts)
    pos = (
        np.array([r.pos for r in refs]).reshape(-1, 3)
        + np.array([r.vel for r in refs]).reshape(-1, 3) * dt[:, None]
    )
    clock = (np.array([r.clock_s for r in refs]) + np.array([r.drift_s_per_s for r in refs]) * dt).tolist()
    return [
        SatState(r.sat, pos[i], r.vel, clock[i], r.drift_s_per_s, r.eph, r.variance_m2)
        for i, r in enumerate(refs)
    ]


def _slot_state(eph: Ephemeris, week: int, k: int) -> SatState:
    """The (cached) state of `eph` at the centre of slot `k` of GPS week `week`."""
    key = (id(eph), week, k)
    ref = _slots.get(key)
    if ref is None or ref.eph is not eph:
        if len(_slots) >= _MAX_SLOTS:
            _slots.clear()
        ref = sat_state(eph, GpsTime(week, k * STATE_SLOT_S))
        _slots[key] = ref
    return ref


def clear_caches() -> None:
    """Forget the slot states and ephemeris selections this process keeps (a benchmark of one
    receiver alone starts from none; results never depend on them)."""
    _slots.clear()
    _selections.clear()


def satellite_states(nav: NavData, t_rx: GpsTime, pseudoranges: Mapping[str, float]) -> dict[str, SatState]:
    """States at emission time for each satellite with a pseudorange (RTKLIB `satposs`).

    t_tx = t_rx - P/c - dts: the travel time first, then the clock polynomial evaluated at the
    satellite-clock time (RTKLIB's order). The ephemeris is the one selected at t_tx.
    Satellites with no usable ephemeris, a non-finite or zero pseudorange, or an unsupported
    system are omitted. Each state is `slotted_state(eph, t_tx)`, bit for bit: times are
    seconds of the receiver's week here (no `GpsTime` per satellite and step, which was a fifth
    of the cost), and the slot states are moved to their emission times together (`_moved`).
    """
    week, tow_rx = t_rx.week, t_rx.tow
    sats: list[str] = []
    refs: list[SatState] = []
    dts: list[float] = []
    for sat, pr in pseudoranges.items():
        if not math.isfinite(pr) or pr == 0.0:
            continue
        # seconds of the receiver's week (below 0 just after a rollover: every use takes the
        # difference to a toe or toc in whole weeks, so an unnormalised second is the same time)
        tow_sv = tow_rx + (-pr / C)
        eph = _select(nav, sat, week, tow_sv)
        if eph is None:
            continue
        tow_tx = tow_sv + (-_clock(eph, week, tow_sv))
        eph_tx = _select(nav, sat, week, tow_tx)
        if eph_tx is None:
            continue
        if eph_tx is not eph:  # crossed a selection boundary: redo the clock with the new one
            eph = eph_tx
            tow_tx = tow_sv + (-_clock(eph, week, tow_sv))
        w = week
        if not 0.0 <= tow_tx < SECONDS_PER_WEEK:  # normalised as GpsTime does: the slot key needs it
            t_tx = GpsTime(week, tow_tx)
            w, tow_tx = t_tx.week, t_tx.tow
        k = round(tow_tx / STATE_SLOT_S)
        sats.append(sat)
        refs.append(_slot_state(eph, w, k))
        dts.append(tow_tx - k * STATE_SLOT_S)
    if not sats:
        return {}
    return dict(zip(sats, _moved(refs, dts), strict=True))


def tgd_m(eph: Ephemeris) -> float:
    """Group delay (m) to subtract from the raw single-frequency code: c*TGD (GPS L1 C/A) or
    c*TGD1 (BeiDou B1I), as RTKLIB's single-frequency `prange`."""
    return C * eph.tgd


def geometric_range(sat_pos: np.ndarray, rx_pos: np.ndarray) -> tuple[float, np.ndarray]:
    """Range with the Sagnac correction, and the unit line of sight receiver -> satellite.

    Equivalent to RTKLIB `geodist`: |s - r| + OMEGA_E*(xs*yr - ys*xr)/c, the first-order effect
    of Earth rotation during signal travel. The GPS rotation rate is used for every system,
    as in RTKLIB (the BDS value differs by 1.5e-14 rad/s: nanometres).
    """
    xs, ys, zs = float(sat_pos[0]), float(sat_pos[1]), float(sat_pos[2])
    xr, yr, zr = float(rx_pos[0]), float(rx_pos[1]), float(rx_pos[2])
    dx, dy, dz = xs - xr, ys - yr, zs - zr
    rho = math.sqrt(dx * dx + dy * dy + dz * dz)
    e = np.array([dx / rho, dy / rho, dz / rho])
    return rho + OMEGA_E_GPS * (xs * yr - ys * xr) / C, e


def rotate_to_receive_frame(
    sat_pos: np.ndarray, travel_time_s: float | np.ndarray, omega: float = OMEGA_E_GPS
) -> np.ndarray:
    """Satellite position(s), (3,) or (n, 3), expressed in the ECEF frame of the reception instant.

    The Earth turns by omega*tau while the signal travels, so an emission-frame position is
    rotated by -omega*tau about Z. Then the plain distance |s' - r| is the Sagnac-corrected
    range (for factors such as GTSAM's PseudorangeFactor that have no Sagnac term). It is the
    exact rotation, which `geometric_range` linearises: they differ by < 1 mm. With (n, 3)
    positions `travel_time_s` holds one travel time per satellite.
    """
    s = np.asarray(sat_pos, dtype=float)
    ang = omega * np.asarray(travel_time_s, dtype=float)
    sa, ca = np.sin(ang), np.cos(ang)
    x, y = s[..., 0], s[..., 1]
    return np.stack([ca * x + sa * y, -sa * x + ca * y, s[..., 2]], axis=-1)
