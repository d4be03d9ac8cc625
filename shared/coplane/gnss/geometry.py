"""What one receiver position sees of an epoch's satellites, all satellites at once.

SPP (where its fit converges), the Doppler rows, DGNSS corrections and the node message all need
the same per-satellite quantities at a receiver position: the Sagnac-corrected range, the line of
sight, elevation and azimuth, and the broadcast atmosphere. They are evaluated here for the whole
epoch in one vectorised call, so every consumer sees the same numbers and none pays numpy's
per-call overhead once per satellite (that per-satellite loop was most of an epoch's cost).
The scalar `ephemeris.geometric_range` stays the reference the tests compare against.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from coplane.geo import ecef_to_geodetic, enu_rotation
from coplane.gnss.atmosphere import IonoModel, iono_model_for, saastamoinen_m
from coplane.gnss.constants import OMEGA_E_GPS, C
from coplane.gnss.ephemeris import rotate_to_receive_frame
from coplane.gtime import GpsTime
from coplane.recording.model import NavData
from coplane.typing import AnyArray as Vec


def sagnac_ranges(sat_pos: Vec, p: Vec) -> tuple[Vec, Vec]:
    """Vectorised `ephemeris.geometric_range`: ranges with the Sagnac term and unit LOS vectors."""
    d = sat_pos - p
    r = np.sqrt(np.einsum("ij,ij->i", d, d))
    e = d / r[:, None]
    return r + OMEGA_E_GPS * (sat_pos[:, 0] * p[1] - sat_pos[:, 1] * p[0]) / C, e


@dataclass(frozen=True)
class SkyView:
    """Satellites (rows, emission-frame ECEF positions) as seen from `position`."""

    position: Vec
    lat: float  # rad
    lon: float  # rad
    h: float  # ellipsoidal height, m
    range_m: Vec  # with the Sagnac term
    los: Vec  # (n, 3) unit vectors receiver -> satellite, ECEF
    el_rad: Vec
    az_rad: Vec  # [0, 2 pi), clockwise from north

    def receive_frame_positions(self, sat_pos: Vec) -> Vec:
        """Satellite positions rotated into the ECEF frame of the reception instant, each by its
        travel time range/c: for factors such as GTSAM's that take a plain satellite position."""
        return rotate_to_receive_frame(sat_pos, self.range_m / C)


# The last view and the last delays computed, with what they were computed from. An agent's epoch
# asks for the same ones three times (SPP where it converged, the Doppler rows and the node
# message's satellites, all of the whole epoch at `SppSolution.model_position`), and they are
# pure functions of their inputs, so a repeated request returns the same (read-only) arrays. One
# entry each, swapped atomically.
_last_view: tuple[bytes, bytes, SkyView] | None = None
# The delays' entry holds the view it was computed for: a key with only the view's id matched a
# later view that the allocator put at a freed one's address (another vehicle of the same epoch,
# in a process that runs several), which then got the other vehicle's delays.
_last_delays: tuple[tuple[object, ...], SkyView, tuple[Vec, Vec]] | None = None


def _frozen(*arrays: Vec) -> None:
    """Make arrays that a cache hands out again read-only, so no caller can change them for the next."""
    for a in arrays:
        a.flags.writeable = False


def sky_view(sat_pos: Vec, position: Vec) -> SkyView:
    """Ranges, lines of sight, elevations and azimuths of `sat_pos` (n, 3) from `position`."""
    global _last_view
    p = np.array(position, dtype=float)
    sp = np.asarray(sat_pos, dtype=float).reshape(-1, 3)
    key_p, key_s = p.tobytes(), sp.tobytes()
    last = _last_view
    if last is not None and last[0] == key_p and last[1] == key_s:
        return last[2]
    lat, lon, h = (float(v) for v in ecef_to_geodetic(p))
    rng, los = sagnac_ranges(sp, p)
    enu = los @ enu_rotation(lat, lon).T
    el = np.arcsin(np.clip(enu[:, 2], -1.0, 1.0))
    az = np.arctan2(enu[:, 0], enu[:, 1]) % (2 * np.pi)
    _frozen(p, rng, los, el, az)
    view = SkyView(p, lat, lon, h, rng, los, el, az)
    _last_view = (key_p, key_s, view)
    return view


def broadcast_delays(
    systems: Sequence[str],
    t: GpsTime,
    view: SkyView,
    nav: NavData,
    iono: bool = True,
    tropo: bool = True,
    iono_model: Literal["broadcast", "rtklib"] = "broadcast",
) -> tuple[Vec, Vec]:
    """(ionospheric, tropospheric) code delays in metres per satellite of `view`.

    The models are the RTKLIB-checked ones of `gnss.atmosphere`, each called once on all the
    satellites it corrects (SPP evaluates this once or twice per epoch, and per-satellite calls
    were its cost; GPS and a BeiDou without coefficients of its own share the GPS model);
    they are only needed without DGNSS, where a base cancels them. "rtklib" iono_model scales the
    GPS Klobuchar to BeiDou B1I, as RTKLIB 2.4.3 does.
    """
    global _last_delays
    key = (tuple(systems), t, tuple(nav.iono.items()), iono, tropo, iono_model)
    last = _last_delays
    if last is not None and last[1] is view and last[0] == key:
        return last[2]  # the entry keeps its view alive, so `is` cannot match another one
    n = len(systems)
    io = np.zeros(n)
    if iono and n:
        # systems that share a model and its coefficients, each with its own scale
        groups: dict[tuple[int, int], tuple[IonoModel, dict[str, float]]] = {}
        for s in dict.fromkeys(systems):  # each system once, in order of first appearance
            model = iono_model_for(s, nav, rtklib=iono_model == "rtklib")
            if model is not None:
                groups.setdefault((id(model.klobuchar), id(model.coeffs)), (model, {}))[1][s] = model.scale
        for model, scales in groups.values():
            m = np.array([x in scales for x in systems])
            delay = model.klobuchar(t, view.lat, view.lon, view.az_rad[m], view.el_rad[m], model.coeffs)
            io[m] = delay * np.array([scales[x] for x in systems if x in scales])  # x * 1.0 is x: exact
    tr = saastamoinen_m(view.lat, view.h, view.el_rad) if tropo else np.zeros(n)
    _frozen(io, tr)
    _last_delays = (key, view, (io, tr))
    return io, tr
