"""Plausibility of a node message against its own measurements: SPP fix and road plane.

A well-formed node message can still carry an SPP fix that its own pseudoranges contradict (a
"displaced fix"), a fix off the Earth's surface, or a road plane that would pull the vehicle far
off (issue 13: d_antenna_m = 1e4 with sigma 1 cm moved a vehicle by 4,000 km). These checks are
pure functions of one message; `admission.Admission` applies them with the thresholds of
`FusionSettings`.

Genuine maxima measured by `tests/fusion_server/test_admission.py` on the bundled recording (4
vehicles x 600 epochs, pc), the real data (Nagoya static, UrbanNav HK TST static, HK Kowloon Tong
rover) and a simulated dense-urban fleet (4 vehicles) are in `GENUINE_MAX`; every threshold below
is several times above them, so 0 genuine messages are rejected.
"""

from __future__ import annotations

import itertools
import math
import statistics

import numpy as np

from coplane.geo import WGS84_A, ecef_to_geodetic, up_vector
from coplane.gnss.constants import C
from coplane.messages import NodeMessage, PlaneReport
from coplane.numeric import row_norms

# Genuine maxima (see the module docstring; re-measured by the tests, which fail if they grow past
# half of a threshold): the worst SPP fix's median |residual| after removing each system's clock,
# its ellipsoidal height range, the worst plane tilt from the local up and the worst SPP-to-plane
# distance.
GENUINE_MAX = {
    "spp_residual_m": 3.8,  # HK Kowloon Tong rover (urban, F9P); simulated: 1.4 (dense urban)
    "spp_height_m": (-33.1, 114.9),  # simulated dense urban (SPP vertical error); real: -2.6..105.7
    "plane_tilt_deg": 8.0,  # bundled recording (its roads' grade plus the fit's tilt)
    "plane_distance_m": 38.0,  # simulated dense urban (SPP's vertical error in the canyon)
}

# A road vehicle's antenna, ellipsoidal height: the Dead Sea shore (-430 m) to the highest roads
# (about 5,800 m), with room for an SPP fix's vertical error; the same band as the consumers'
# check of solved positions (coplane.bus.trust).
SPP_HEIGHT_M = (-1_000.0, 10_000.0)
# SPP self-consistency: median |pseudorange residual| (each system's clock removed) of the used
# satellites at the reported fix: 6.5x the genuine maximum (GENUINE_MAX). Measured on the bundled
# recording, a fix displaced by 300 m gives 20..100 m (median over epochs and directions 100 m),
# by 1 km 71..340 m: every displacement above ~400 m is caught, most above ~80 m. A displaced SPP
# fix is only the estimator's initial guess (the pseudoranges decide), so the margin goes to
# never rejecting a genuine fix.
SPP_RESIDUAL_M = 25.0
MIN_SATS_FOR_RESIDUAL = 5  # fewer used satellites cannot show a displaced fix (4 unknowns + 1)
# Road planes: the steepest public roads are ~35 % (19 degrees); the plane is fitted in the
# vehicle's frame with its own tilt error on top.
PLANE_TILT_DEG = 30.0
# SPP-to-plane distance at the antenna: SPP's vertical error in urban canyons is tens of metres,
# so the bound is loose (4x the genuine maximum); it catches planes that would pull the vehicle
# far off (the 1e4 m offset of issue 13) and bounds what a plausible-looking forged plane can do.
PLANE_DISTANCE_M = 150.0
# A plane near the surface has |d| (d = -n.p for p on the plane) between the smallest Earth radius
# plus the lowest height, times cos of the largest tilt, and the largest radius plus the highest.
_MIN_RADIUS_M = WGS84_A * (1.0 - 1.0 / 298.257223563) + SPP_HEIGHT_M[0]
_MAX_PLANE_D_M = WGS84_A + SPP_HEIGHT_M[1]


def spp_residual_m(msg: NodeMessage) -> float | None:
    """Median |pseudorange residual| of the used satellites at the reported SPP fix, each system's
    clock removed by its median (robust to NLOS outliers); None when it cannot tell (no fix, too
    few satellites). The medians of a few dozen values are Python's (`statistics.median`, the
    same numbers as numpy's): numpy's call overhead made this check cost more than decoding the
    message."""
    p = msg.spp.position_ecef_m
    s = msg.satellites
    used = np.array(s.used, dtype=bool)
    if p is None or int(used.sum()) < MIN_SATS_FOR_RESIDUAL:
        return None
    pos = np.asarray(p, dtype=float)
    sat = np.array(s.sat_pos_ecef_m, dtype=float)[used]
    rho = np.array(s.rho_m, dtype=float)[used] + C * np.array(s.sat_clock_s, dtype=float)[used]
    res = (rho - row_norms(sat - pos)).tolist()
    by_system: dict[str, list[float]] = {}
    for sat_id, r in zip(itertools.compress(s.sat, s.used), res, strict=True):
        by_system.setdefault(sat_id[0], []).append(r)
    clock_free: list[float] = []
    for values in by_system.values():
        m = statistics.median(values)
        clock_free.extend(abs(r - m) for r in values)
    return float(statistics.median(clock_free))


def spp_height_m(msg: NodeMessage) -> float | None:
    """Ellipsoidal height of the reported SPP position, if any."""
    p = msg.spp.position_ecef_m
    return None if p is None else float(ecef_to_geodetic(np.asarray(p, dtype=float))[2])


def spp_problem(msg: NodeMessage, max_residual_m: float) -> str | None:
    """Why the message's SPP position is implausible (off the Earth's surface, or not where its
    own pseudoranges put it), or None."""
    h = spp_height_m(msg)
    if h is not None and not SPP_HEIGHT_M[0] <= h <= SPP_HEIGHT_M[1]:
        return f"SPP height {h:.0f} m is outside {SPP_HEIGHT_M[0]:.0f}..{SPP_HEIGHT_M[1]:.0f} m"
    if msg.spp.ok:
        r = spp_residual_m(msg)
        if r is not None and r > max_residual_m:
            return f"SPP fix is {r:.0f} m (median residual) from its own pseudoranges"
    return None


def plane_tilt_deg(plane: PlaneReport, at: tuple[float, float, float]) -> float:
    """Angle between the plane's normal and the local geodetic up at `at`."""
    n = np.asarray(plane.normal, dtype=float)
    c = float(np.clip(np.dot(n, up_vector(np.asarray(at, dtype=float))), -1.0, 1.0))
    return math.degrees(math.acos(c))


def plane_distance_m(plane: PlaneReport, at: tuple[float, float, float]) -> float:
    """Signed distance of `at` from the plane (n.p + d, positive above)."""
    assert plane.normal is not None and plane.d_antenna_m is not None
    return float(
        np.dot(np.asarray(plane.normal, dtype=float), np.asarray(at, dtype=float)) + plane.d_antenna_m
    )


def plane_problem(msg: NodeMessage, max_tilt_deg: float, max_distance_m: float) -> str | None:
    """Why the message's plane is implausible, or None. Its offset must put it near the Earth's
    surface; against the SPP fix and against the plane's own centroid (whichever are reported;
    genuine planes always have a centroid), the normal must be near the local up and the point
    near the plane. A plane with neither cannot be checked and is implausible."""
    pl = msg.plane
    if pl is None or pl.status == "unavailable" or pl.normal is None or pl.d_antenna_m is None:
        return None
    if not _MIN_RADIUS_M * math.cos(math.radians(max_tilt_deg)) <= abs(pl.d_antenna_m) <= _MAX_PLANE_D_M:
        return f"plane offset {pl.d_antenna_m:.0f} m does not put it near the Earth's surface"
    refs = [
        (what, p) for what, p in (("SPP fix", msg.spp.position_ecef_m), ("centroid", pl.centroid_ecef_m)) if p
    ]
    if not refs:
        return "plane has neither an SPP fix nor a centroid to check it against"
    for what, p in refs:
        h = float(ecef_to_geodetic(np.asarray(p, dtype=float))[2])
        if not SPP_HEIGHT_M[0] <= h <= SPP_HEIGHT_M[1]:
            return f"plane {what} height {h:.0f} m is off the Earth's surface"
        tilt = plane_tilt_deg(pl, p)
        if tilt > max_tilt_deg:
            return f"plane normal is {tilt:.1f} deg from the local up at the {what}"
        dist = plane_distance_m(pl, p)
        if abs(dist) > max_distance_m:
            return f"the {what} is {dist:.0f} m from the plane"
    return None
