"""Road network of the simulator: a closed urban circuit with lanes, turns and a 3-D vertical profile.

Why this shape: the paper's vehicles all drive the same route in two lanes of one direction
(Section V), and its plane constraint only works if the road is locally planar. The circuit
therefore mixes the cases that matter for a road-plane fit: flat tangents, constant grades of
3-5 % (planar, tilted), vertical curves (a crest or sag, where one plane over ~50 m does *not*
fit), and an underpass whose bridge deck blocks GNSS entirely.

Geometry:
* centreline = straight legs between waypoints joined by circular fillets (radius R), in a local
  East-North frame at the scenario origin; `s` is arc length along the centreline, periodic in L;
* lateral offset `y` is positive to the left of the driving direction; lane k of n sits at
  y = (k - (n-1)/2) * lane width (lane 0 is the right-hand lane);
* the vertical profile z(s) is the integral of a grade that is constant on tangents and varies
  linearly inside each vertical curve (the standard parabolic curve of highway design, AASHTO
  Green Book ch. 3), so z and its slope are continuous;
* "flat" means constant *ellipsoidal* height (z is added to the origin height, not to a tangent
  plane), so a 1.3 km flat leg follows the Earth's curvature as a real road does.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np
import pymap3d as pm

from coplane.typing import AnyArray

SECTION_KINDS: tuple[str, ...] = ("open", "medium", "deep", "underpass")


@dataclass(frozen=True)
class GradeChange:
    """A point of vertical intersection: at `s_m` the grade becomes `grade` over a curve `curve_m` long."""

    s_m: float
    grade: float
    curve_m: float


class VerticalProfile:
    """z(s) relative to the origin height for a closed loop (z(0) = z(L) = 0, grade periodic).

    Grades are piecewise constant with linear transitions (vertical curves) centred on each
    change point; z is integrated exactly (piecewise quadratic).
    """

    def __init__(self, length_m: float, changes: tuple[GradeChange, ...], start_grade: float = 0.0) -> None:
        self.length_m = float(length_m)
        self.changes = tuple(sorted(changes, key=lambda c: c.s_m))
        self.start_grade = start_grade
        # breakpoints of the grade function g(s): (s, g) pairs, linear in between
        pts: list[tuple[float, float]] = [(0.0, start_grade)]
        g = start_grade
        for c in self.changes:
            a, b = c.s_m - c.curve_m / 2.0, c.s_m + c.curve_m / 2.0
            if a < pts[-1][0] - 1e-9:
                raise ValueError(f"vertical curve at s={c.s_m} overlaps the previous one")
            pts.append((a, g))
            pts.append((b, c.grade))
            g = c.grade
        if pts[-1][0] > self.length_m:
            raise ValueError("vertical curves extend beyond the loop length")
        pts.append((self.length_m, g))
        self._s = np.array([p[0] for p in pts])
        self._g = np.array([p[1] for p in pts])
        # z at each breakpoint: trapezoid rule is exact for a piecewise-linear grade
        dz = np.diff(self._s) * (self._g[:-1] + self._g[1:]) / 2.0
        self._z = np.concatenate([[0.0], np.cumsum(dz)])

    @property
    def closure_error_m(self) -> float:
        """z(L) - z(0): zero for a loop that closes."""
        return float(self._z[-1])

    def grade(self, s: AnyArray | float) -> AnyArray:
        ss = np.mod(np.asarray(s, dtype=float), self.length_m)
        return np.interp(ss, self._s, self._g)

    def z(self, s: AnyArray | float) -> AnyArray:
        ss = np.mod(np.asarray(s, dtype=float), self.length_m)
        i = np.clip(np.searchsorted(self._s, ss, side="right") - 1, 0, len(self._s) - 2)
        s0, g0 = self._s[i], self._g[i]
        ds = np.maximum(self._s[i + 1] - s0, 1e-12)
        slope = (self._g[i + 1] - g0) / ds
        u = ss - s0
        return self._z[i] + g0 * u + 0.5 * slope * u * u

    def curvature(self, s: AnyArray | float) -> AnyArray:
        """d(grade)/ds (1/m): non-zero only inside vertical curves."""
        ss = np.mod(np.asarray(s, dtype=float), self.length_m)
        i = np.clip(np.searchsorted(self._s, ss, side="right") - 1, 0, len(self._s) - 2)
        ds = np.maximum(self._s[i + 1] - self._s[i], 1e-12)
        return (self._g[i + 1] - self._g[i]) / ds

    def vertical_curves(self) -> list[tuple[float, float, float, float]]:
        """(start, end, grade before, grade after) of every vertical curve."""
        out = []
        g = self.start_grade
        for c in self.changes:
            out.append((c.s_m - c.curve_m / 2.0, c.s_m + c.curve_m / 2.0, g, c.grade))
            g = c.grade
        return out


@dataclass(frozen=True)
class RoadRaise:
    """A re-surfaced section: the road between `s_start_m` and `s_end_m` lies `dz_m` higher, with
    cosine ramps `ramp_m` long inside the section (z and grade stay continuous, as a real overlay
    is feathered in). The road-map benchmarks raise a section between runs to check that the map
    notices the change and re-learns it."""

    s_start_m: float
    s_end_m: float
    dz_m: float
    ramp_m: float = 20.0

    def __post_init__(self) -> None:
        if not (self.s_end_m - self.s_start_m >= 2.0 * self.ramp_m > 0.0):
            raise ValueError(f"raise {self}: the section must hold both ramps")

    def weights(self, s: AnyArray) -> tuple[AnyArray, AnyArray, AnyArray]:
        """w(s) in [0, 1] and its first and second derivatives along s."""
        w, dw, d2w = np.zeros(s.shape), np.zeros(s.shape), np.zeros(s.shape)
        k = math.pi / self.ramp_m
        up = (s >= self.s_start_m) & (s < self.s_start_m + self.ramp_m)
        down = (s > self.s_end_m - self.ramp_m) & (s <= self.s_end_m)
        flat = (s >= self.s_start_m + self.ramp_m) & (s <= self.s_end_m - self.ramp_m)
        w[flat] = 1.0
        for m, u, sign in ((up, s - self.s_start_m, 1.0), (down, self.s_end_m - s, -1.0)):
            w[m] = 0.5 * (1.0 - np.cos(k * u[m]))
            dw[m] = sign * 0.5 * k * np.sin(k * u[m])
            d2w[m] = 0.5 * k * k * np.cos(k * u[m])
        return w, dw, d2w


class RaisedProfile(VerticalProfile):
    """A vertical profile with re-surfaced sections added on top (see RoadRaise)."""

    def __init__(self, base: VerticalProfile, raises: tuple[RoadRaise, ...]) -> None:
        self.__dict__.update(base.__dict__)
        self.raises = raises

    def _sum(self, s: AnyArray | float, which: int) -> AnyArray:
        ss = np.mod(np.asarray(s, dtype=float), self.length_m)
        out = np.zeros(ss.shape)
        for r in self.raises:
            out = out + r.dz_m * r.weights(ss)[which]
        return out

    def z(self, s: AnyArray | float) -> AnyArray:
        return super().z(s) + self._sum(s, 0)

    def grade(self, s: AnyArray | float) -> AnyArray:
        return super().grade(s) + self._sum(s, 1)

    def curvature(self, s: AnyArray | float) -> AnyArray:
        return super().curvature(s) + self._sum(s, 2)


def closing_profile(
    length_m: float, changes: tuple[GradeChange, ...], last_curve_m: float = 50.0
) -> VerticalProfile:
    """A profile whose last change point is moved so that the loop closes (z(L) = 0).

    The last change must return the grade to the start grade; the one before it sets the
    grade used to take up the remaining height. Raises if no position closes the loop.
    """
    *head, before, last = changes
    trial = VerticalProfile(length_m, (*head, before, GradeChange(last.s_m, last.grade, last_curve_m)))
    err = trial.closure_error_m
    g_run = before.grade - last.grade
    if g_run == 0.0:
        raise ValueError("the last two grade changes cannot close the loop")
    moved = GradeChange(last.s_m - err / g_run, last.grade, last_curve_m)
    prof = VerticalProfile(length_m, (*head, before, moved))
    if abs(prof.closure_error_m) > 1e-6:
        raise ValueError(f"profile does not close: {prof.closure_error_m:.3f} m")
    return prof


@dataclass(frozen=True)
class _Prim:
    s0: float
    length: float
    kind: str  # "line" | "arc"
    a: tuple[float, float]  # line: start point; arc: centre
    t: tuple[float, float]  # line: unit direction; arc: unused
    radius: float = 0.0
    phi0: float = 0.0  # arc: polar angle of the start point about the centre
    turn: float = 0.0  # arc: +1 left (counter-clockwise), -1 right


class Road:
    """The centreline of a closed circuit of straight legs and circular turns, plus lanes.

    `legs()` gives the straight parts (where buildings stand); `turns()` the fillets.
    All methods take arrays of `s` (wrapped modulo the loop length) and are vectorised.
    """

    def __init__(
        self,
        waypoints_en: tuple[tuple[float, float], ...],
        corner_radius_m: float,
        lanes: int,
        lane_width_m: float,
        profile_changes: tuple[GradeChange, ...] = (),
        closing_curve_m: float = 50.0,
    ) -> None:
        pts = np.asarray(waypoints_en, dtype=float)
        n = len(pts)
        if n < 3:
            raise ValueError("a circuit needs at least three waypoints")
        self.lanes = lanes
        self.lane_width_m = lane_width_m
        prims: list[_Prim] = []
        # tangent points of the fillet at each vertex
        t_in, t_out, arcs = [], [], []
        for i in range(n):
            p_prev, p, p_next = pts[i - 1], pts[i], pts[(i + 1) % n]
            d1 = (p - p_prev) / np.linalg.norm(p - p_prev)
            d2 = (p_next - p) / np.linalg.norm(p_next - p)
            cross = d1[0] * d2[1] - d1[1] * d2[0]
            ang = math.atan2(cross, float(d1 @ d2))  # signed turn angle, + = left
            tl = corner_radius_m * math.tan(abs(ang) / 2.0)
            t_in.append(p - d1 * tl)
            t_out.append(p + d2 * tl)
            turn = 1.0 if ang > 0 else -1.0
            left1 = np.array([-d1[1], d1[0]])
            centre = t_in[-1] + left1 * corner_radius_m * turn
            v0 = t_in[-1] - centre
            arcs.append((centre, math.atan2(v0[1], v0[0]), turn, corner_radius_m * abs(ang)))
        s = 0.0
        self._legs: list[tuple[float, float]] = []
        self._turns: list[tuple[float, float, float]] = []
        for i in range(n):
            a, b = t_out[i], t_in[(i + 1) % n]
            seg = b - a
            ln = float(np.linalg.norm(seg))
            if ln <= 0.0:
                raise ValueError(f"leg {i} is shorter than its corner fillets")
            prims.append(_Prim(s, ln, "line", (float(a[0]), float(a[1])), (seg[0] / ln, seg[1] / ln)))
            self._legs.append((s, s + ln))
            s += ln
            c, phi0, turn, alen = arcs[(i + 1) % n]
            prims.append(
                _Prim(s, alen, "arc", (float(c[0]), float(c[1])), (0.0, 0.0), corner_radius_m, phi0, turn)
            )
            self._turns.append((s, s + alen, turn))
            s += alen
        self.length_m = s
        self._prims = prims
        self._s0 = np.array([p.s0 for p in prims])
        self.profile = (
            closing_profile(s, profile_changes, closing_curve_m)
            if profile_changes
            else (VerticalProfile(s, ()))
        )

    # --- plan view ---------------------------------------------------------------------------

    def legs(self) -> list[tuple[float, float]]:
        """(s_start, s_end) of each straight leg, in driving order."""
        return list(self._legs)

    def turns(self) -> list[tuple[float, float, float]]:
        """(s_start, s_end, +1 left / -1 right) of each turn."""
        return list(self._turns)

    def lane_offset(self, lane: AnyArray | int) -> AnyArray:
        return (np.asarray(lane, dtype=float) - (self.lanes - 1) / 2.0) * self.lane_width_m

    def frame(self, s: AnyArray | float) -> tuple[AnyArray, AnyArray, AnyArray]:
        """Centreline point (..., 2), unit heading (..., 2) and signed plan curvature (1/m, + left)."""
        ss = np.mod(np.asarray(s, dtype=float), self.length_m)
        idx = np.clip(np.searchsorted(self._s0, ss, side="right") - 1, 0, len(self._prims) - 1)
        p = np.zeros((*ss.shape, 2))
        t = np.zeros((*ss.shape, 2))
        k = np.zeros(ss.shape)
        for j, pr in enumerate(self._prims):
            m = idx == j
            if not np.any(m):
                continue
            u = ss[m] - pr.s0
            if pr.kind == "line":
                p[m, 0] = pr.a[0] + u * pr.t[0]
                p[m, 1] = pr.a[1] + u * pr.t[1]
                t[m, 0], t[m, 1] = pr.t
            else:
                phi = pr.phi0 + pr.turn * u / pr.radius
                p[m, 0] = pr.a[0] + pr.radius * np.cos(phi)
                p[m, 1] = pr.a[1] + pr.radius * np.sin(phi)
                t[m, 0] = -pr.turn * np.sin(phi)
                t[m, 1] = pr.turn * np.cos(phi)
                k[m] = pr.turn / pr.radius
        return p, t, k

    def plan_point(self, s: AnyArray | float, y: AnyArray | float) -> AnyArray:
        """East-North point at arc length `s` and lateral offset `y` (left positive)."""
        p, t, _ = self.frame(s)
        yy = np.asarray(y, dtype=float)[..., None]
        left = np.stack([-t[..., 1], t[..., 0]], axis=-1)
        return p + yy * left

    # --- 3-D ---------------------------------------------------------------------------------

    def antenna_enu(self, s: AnyArray | float, y: AnyArray | float, height_m: AnyArray | float) -> AnyArray:
        """Local (E, N, U) of an antenna `height_m` above the road surface along the surface normal.

        U is the height above the origin's ellipsoidal height. The car sits on the road, so its
        roof antenna is offset along the surface normal (n = (-g*t, 1)/sqrt(1+g^2) with grade g
        and heading t), not straight up; on a 5 % grade that moves a 2 m antenna 0.1 m back.
        """
        p, t, _ = self.frame(s)
        yy = np.asarray(y, dtype=float)
        left = np.stack([-t[..., 1], t[..., 0]], axis=-1)
        g = self.profile.grade(s)
        h = np.asarray(height_m, dtype=float)
        norm = np.sqrt(1.0 + g * g)
        e = p[..., 0] + yy * left[..., 0] - h * g * t[..., 0] / norm
        n = p[..., 1] + yy * left[..., 1] - h * g * t[..., 1] / norm
        u = self.profile.z(s) + h / norm
        return np.stack([e, n, u], axis=-1)


def enu_to_ecef_curved(
    enu: AnyArray, origin_lat_deg: float, origin_lon_deg: float, origin_h_m: float
) -> AnyArray:
    """Local (E, N, U) to ECEF with U measured as ellipsoidal height above the origin's height.

    Latitude and longitude come from the tangent-plane point (distortion < 1 mm within 2 km);
    the height is origin_h + U, so flat roads keep a constant ellipsoidal height.
    """
    a = np.asarray(enu, dtype=float)
    lat, lon, _ = pm.enu2geodetic(
        a[..., 0], a[..., 1], np.zeros(a.shape[:-1]), origin_lat_deg, origin_lon_deg, 0.0
    )
    x, y, z = pm.geodetic2ecef(lat, lon, origin_h_m + a[..., 2])
    return np.stack([np.asarray(x), np.asarray(y), np.asarray(z)], axis=-1)


@dataclass(frozen=True)
class Section:
    s0: float
    s1: float
    kind: str


class Sections:
    """Section kinds along the loop (open sky / medium / deep canyon / underpass)."""

    def __init__(self, length_m: float, spans: tuple[tuple[float, str], ...]) -> None:
        """`spans` = (start s, kind) pairs in increasing s; the first must start at 0."""
        if not spans or spans[0][0] != 0.0:
            raise ValueError("sections must start at s = 0")
        for _, k in spans:
            if k not in SECTION_KINDS:
                raise ValueError(f"unknown section kind {k!r}; known: {', '.join(SECTION_KINDS)}")
        starts = [s for s, _ in spans]
        if any(b <= a for a, b in itertools.pairwise(starts)) or starts[-1] >= length_m:
            raise ValueError("section starts must increase and lie inside the loop")
        self.length_m = length_m
        self._s0 = np.array(starts)
        self._kinds = [k for _, k in spans]
        self.sections = tuple(
            Section(s, (starts[i + 1] if i + 1 < len(starts) else length_m), k)
            for i, (s, k) in enumerate(spans)
        )

    def index(self, s: AnyArray | float) -> AnyArray:
        """Index into SECTION_KINDS of the section at each s."""
        ss = np.mod(np.asarray(s, dtype=float), self.length_m)
        i = np.searchsorted(self._s0, ss, side="right") - 1
        codes = np.array([SECTION_KINDS.index(k) for k in self._kinds])
        return codes[i]

    def kind(self, s: float) -> str:
        return SECTION_KINDS[int(self.index(s))]
