"""Synthetic roads and passes for the road-surface map's tests."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pytest

from coplane.geo import ecef_to_geodetic, enu_to_ecef, geodetic_to_ecef, up_vector
from coplane.roadmap import PassEvidence
from coplane.typing import Vec


@dataclass(frozen=True)
class Road:
    """A planar true road: ellipsoidal height h0 + grade_e e + grade_n n at local (e, n) metres of
    a reference point (ENU about (lat0, lon0) on the ellipsoid)."""

    lat0: float = np.radians(48.137)
    lon0: float = np.radians(11.575)
    h0: float = 520.0
    grade_e: float = 0.03
    grade_n: float = -0.01

    def height(self, e: float, n: float) -> float:
        return self.h0 + self.grade_e * e + self.grade_n * n

    def road_ecef(self, e: float, n: float) -> Vec:
        ref = geodetic_to_ecef(self.lat0, self.lon0, 0.0)
        lat, lon, _ = ecef_to_geodetic(enu_to_ecef(np.array([e, n, 0.0]), ref))
        return geodetic_to_ecef(float(lat), float(lon), self.height(e, n))

    def antenna_ecef(self, e: float, n: float, antenna_h: float, dh: float = 0.0) -> Vec:
        """The antenna above the road point, `dh` higher than it should be."""
        p = self.road_ecef(e, n)
        return p + (antenna_h + dh) * up_vector(p)


MakePass = Callable[..., PassEvidence]


def make_pass_fn(
    rng: np.random.Generator,
    *,
    a: float = 0.0,
    b: float = 0.0,
    c: float = 0.0,
    lane_n: float = 0.0,
    t: float = 0.0,
    vid: str = "v1",
    n_pts: int = 19,
    sigma: float = 0.1,
    shared: bool = True,
    point_sigma: float = 0.0,
    e_span: tuple[float, float] = (-9.0, 9.0),
) -> PassEvidence:
    """One pass along local east at north = lane_n on the plane a + b e + c n (relative to h0):
    one shared error N(0, sigma) (a vehicle's error over a pass) plus N(0, point_sigma) per point;
    each point reports `sigma`."""
    e = np.linspace(e_span[0], e_span[1], n_pts)
    n = np.full(n_pts, lane_n)
    u = a + b * e + c * n
    if shared and sigma > 0:
        u = u + rng.normal(0.0, sigma)
    if point_sigma > 0:
        u = u + rng.normal(0.0, point_sigma, n_pts)
    return PassEvidence(vid, t, np.column_stack([e, n, u]), np.full(n_pts, sigma))


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(14)


@pytest.fixture
def make_pass(rng: np.random.Generator) -> MakePass:
    def f(**kw: object) -> PassEvidence:
        return make_pass_fn(rng, **kw)  # type: ignore[arg-type]

    return f


@pytest.fixture
def road() -> Road:
    return Road()
