"""Least-squares plane fit by SVD (paper eqs. 6-11, 15) and its translation to antenna height.

Conventions used everywhere in coplane (fit, detection, the plane factor, the messages):

- a plane is ``n . p + d = 0`` with ``n`` a unit vector oriented UPWARD (``n . up >= 0`` with ``up``
  the ellipsoidal normal at the centroid), so the sign of ``n`` - and with it the sign of ``d`` and
  of every signed distance - is well defined: positive means above the plane;
- the antenna plane is the road plane moved ``h`` along ``n``: ``d_antenna = d_road - h`` (a point
  ``p_r + h n`` gives ``n . p + d_road = h``). This replaces the sign rule of eq. (13), which picks
  ``+h`` or ``-h`` from the sign of ``P^D``. ``P^D = -n . centroid`` tells on which side of the plane
  the coordinate ORIGIN lies, which is "below" only because the ECEF origin is the Earth's centre and
  the SVD's arbitrary normal sign cancels out of the product. In any other frame (ENU about a nearby
  point, a local map frame), or for a plane through the origin, eq. (13) can move the plane down.
  With an upward normal the direction is "up" by construction, in every frame;
- the factor form (eqs. 22-24): ``u_PC = -n`` and ``P'^D = d``, error ``P'^D - p . u_PC`` which is
  the signed height ``n . p + d`` of ``p`` above the plane. `constraint_error` is that definition.

Degenerate inputs (fewer than 3 points, coincident or collinear points) give a `Degenerate`
result, never a plane with an arbitrary or NaN normal.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from coplane.geo import up_vector
from coplane.typing import Vec

DEGENERATE_ABS_M = 1e-6
"""Middle singular value (m) at or below which points count as collinear: float64 ECEF coordinates
carry ~1e-9 m of rounding, so exactly collinear input gives s2 ~ 1e-8; a real road is metres wide."""

DEGENERATE_REL = 1e-9
"""... or at or below this fraction of the largest singular value (scale-free form of the same)."""


def _as_points(points: ArrayLike) -> Vec:
    p = np.asarray(points, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"points must have shape (N, 3), got {p.shape}")
    if not np.isfinite(p).all():
        raise ValueError("points contain NaN or infinite coordinates")
    return p


def unit_vector(v: Vec) -> Vec:
    """`v / np.linalg.norm(v)` for a 1-D vector, bit for bit: the same sqrt of `v.dot(v)`.

    Written out because RANSAC normalises a normal per hypothesis and norm's generic dispatch
    costs more than the arithmetic on a 3-vector.
    """
    return np.asarray(v / np.sqrt(v.dot(v)), dtype=float)


def centred_svd(points: Vec) -> tuple[Vec, Vec, Vec]:
    """Centroid (eq. 6), singular values (descending) and right singular vectors (rows) of A (eq. 8).

    The centroid is computed in two passes about the first point so that Earth-scale ECEF
    coordinates (~6.4e6 m) do not cost precision in the centred matrix.
    """
    ref = points[0]
    local = points - ref
    c_local = np.add.reduce(local, axis=0) / local.shape[0]  # what .mean(axis=0) computes, less overhead
    a = local - c_local
    _, s, vt = np.linalg.svd(a, full_matrices=False)
    if s.shape[0] < 3:  # fewer than 3 rows: pad so that s always has 3 entries
        s = np.concatenate([s, np.zeros(3 - s.shape[0])])
    return ref + c_local, s, vt


def is_degenerate(s: Vec) -> bool:
    """Collinear or coincident: the second singular value vanishes, so the normal is undefined."""
    s0, s1 = float(s[0]), float(s[1])
    return s1 <= max(DEGENERATE_ABS_M, DEGENERATE_REL * s0)


def antenna_offset(d_road: float, antenna_height_m: float) -> float:
    """Eq. (12)-(13) done geometrically: the parallel plane ``h`` above, along the upward unit normal."""
    return d_road - antenna_height_m


def constraint_error(normal: ArrayLike, p_d: float, p: ArrayLike) -> float:
    """Paper eq. (24): ``f = P'^D - p . u_PC`` with ``u_PC = -n`` (eq. 23); equals ``n . p + P'^D``.

    Signed metres: positive when ``p`` is above the plane. Shared by the factor code and the tests.
    """
    u_pc = -np.asarray(normal, dtype=float)
    return float(p_d - np.dot(np.asarray(p, dtype=float), u_pc))


@dataclass(frozen=True, eq=False)
class Degenerate:
    """No plane: fewer than 3 points, or all points (numerically) on one line or one point."""

    reason: str
    n_points: int
    singular_values: Vec


@dataclass(frozen=True, eq=False)
class PlaneFit:
    """A fitted plane ``n . p + d = 0`` with ``n`` unit and upward (see module docstring)."""

    normal: Vec
    d: float
    centroid: Vec
    singular_values: Vec  # s1 >= s2 >= s3 of the centred points (eq. 9)
    up: Vec  # the local up used to orient the normal
    n_points: int

    @property
    def conditioning(self) -> float:
        """s2 / s3: lateral spread over off-plane scatter; inf for points exactly on a plane."""
        s2, s3 = float(self.singular_values[1]), float(self.singular_values[2])
        return math.inf if s3 <= 0.0 else s2 / s3

    @property
    def tilt_deg(self) -> float:
        """Angle between the normal and local up (0 for a level road; 2.86 deg for a 5% grade)."""
        return math.degrees(math.acos(min(1.0, max(-1.0, float(self.normal @ self.up)))))

    @property
    def u_pc(self) -> Vec:
        """Eq. (23)'s unit vector ``u_PC = -n``."""
        return -self.normal

    def signed_distances(self, points: ArrayLike) -> Vec:
        """Eq. (15) without the absolute value: height of each point above the plane (m)."""
        p = np.asarray(points, dtype=float)
        return np.asarray((p - self.centroid) @ self.normal, dtype=float)

    def distances(self, points: ArrayLike) -> Vec:
        """Eq. (15): point-to-plane distances (m); the normal is unit, so no division is needed."""
        return np.abs(self.signed_distances(points))

    def translated(self, height_m: float) -> PlaneFit:
        """The parallel plane ``height_m`` above (eqs. 12-13 done along the upward normal)."""
        return PlaneFit(
            normal=self.normal,
            d=antenna_offset(self.d, height_m),
            centroid=self.centroid + height_m * self.normal,
            singular_values=self.singular_values,
            up=self.up,
            n_points=self.n_points,
        )

    def constraint_error(self, p: ArrayLike) -> float:
        """Eq. (24) against this plane (use the antenna plane for the factor): ``n . p + d``."""
        return constraint_error(self.normal, self.d, p)


def _readonly(a: Vec) -> Vec:
    a = np.array(a, dtype=float, copy=True)
    a.flags.writeable = False
    return a


def fit_plane(points: ArrayLike, up: ArrayLike | None = None) -> PlaneFit | Degenerate:
    """Total-least-squares plane through `points` (N, 3), eqs. (6)-(11), normal oriented upward.

    `up` is the direction that decides the normal's sign; by default the ellipsoidal up at the
    centroid (points in ECEF). Pass it explicitly for points in a local frame.
    """
    p = _as_points(points)
    n_pts = p.shape[0]
    if n_pts < 3:
        return Degenerate(f"degenerate: {n_pts} point(s), a plane needs 3", n_pts, np.zeros(3))
    centroid, s, vt = centred_svd(p)
    if is_degenerate(s):
        what = "coincident" if s[0] <= DEGENERATE_ABS_M else "collinear"
        return Degenerate(
            f"degenerate: the {n_pts} points are {what} (s2 = {s[1]:.2g} m)", n_pts, _readonly(s)
        )
    normal = unit_vector(vt[2])  # eq. (10): right singular vector of the smallest s
    u = unit_vector(up_vector(centroid) if up is None else np.asarray(up, dtype=float))
    if float(normal @ u) < 0.0:
        normal = -normal
    d = -float(normal @ centroid)  # eq. (11)
    return PlaneFit(
        normal=_readonly(normal),
        d=d,
        centroid=_readonly(centroid),
        singular_values=_readonly(s),
        up=_readonly(u),
        n_points=n_pts,
    )


def plane_through_three(points: Vec) -> tuple[Vec, float] | None:
    """Unoriented plane (normal, d) through three points for RANSAC; None if they are collinear.

    Uses the same SVD and the same degeneracy rule as `fit_plane`, so 'collinear' means one thing.
    """
    centroid, s, vt = centred_svd(points)
    if is_degenerate(s):
        return None
    normal = unit_vector(vt[2])
    return normal, -float(normal @ centroid)
