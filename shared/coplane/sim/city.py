"""The `city` scenario's layout: a street grid, rolling terrain, buildings per street, loops, platoons.

Why: the one-loop scenarios put every vehicle on the same 3.9 km circuit, which is fine for the
paper's 4 cars but not for load generation with 1000+ vehicles, where the fusion side must see
groups that meet and part. The city is a grid of streets (blocks of 220-420 m, a few km wide,
growing with sqrt(vehicles) so the density stays about the same); each *loop* is the boundary of
a rectangle of 1-4 x 1-4 blocks, so loops of different sizes share streets and cross each other.
Vehicles drive in platoons of 2-6 on one loop each (coplane.sim.motion per loop), so platoons on
crossing or shared streets come within UWB range of each other and part again.

What is shared has to agree between loops, so it belongs to the city, not to a loop:
* the ground height is one smooth terrain z(E, N) (three gentle waves, grade at most ~5 %), and
  each loop's vertical profile samples it (a per-loop grade-change profile would put two cars on
  the same street at different heights);
* buildings stand along street segments (both sides, none within `clear_m` of a crossing) and
  each loop's canyon rows are the buildings of the streets it drives along;
* every loop is driven clockwise on the right-hand carriageway (its centreline `inset` to the
  right of the street's), so loops sharing a street in the same direction share lanes and
  opposite directions are apart. Car following acts within a loop only.
See docs/simulator.md (City).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field

import numpy as np

from coplane.sim.canyon import BuildingParams
from coplane.sim.road import Road, VerticalProfile
from coplane.typing import AnyArray


def _city_buildings() -> dict[str, BuildingParams]:
    """Urban-loop-like blocks; setbacks are from the street centre (two carriageways of 7 m)."""
    return {
        "open": BuildingParams(height_m=(3.0, 9.0), setback_m=(30.0, 45.0), fill=0.25),
        "medium": BuildingParams(height_m=(10.0, 25.0), setback_m=(19.0, 27.0), fill=0.75),
        "deep": BuildingParams(height_m=(30.0, 70.0), setback_m=(20.0, 27.0), fill=0.85, gap_m=(5.0, 20.0)),
    }


@dataclass(frozen=True)
class CityParams:
    """How the city is laid out; every draw comes from the seed (streams "city", "city-canyon")."""

    side_at_1000_m: float = 3000.0  # side of the square city for 1000 vehicles, scales with sqrt(N)
    side_limits_m: tuple[float, float] = (1000.0, 6000.0)
    block_m: tuple[float, float] = (220.0, 420.0)  # street spacing
    vehicles_per_loop: float = 25.0
    min_loops: int = 4
    loop_blocks: tuple[int, int] = (1, 4)  # a loop encloses 1-4 blocks in each direction
    platoon_size: tuple[int, int] = (2, 6)
    platoon_factor: tuple[float, float] = (0.82, 1.0)  # desired speed / limit, per platoon
    member_factor_spread: float = 0.02
    platoon_gap_m: tuple[float, float] = (12.0, 30.0)  # bumper to bumper inside a platoon
    corner_radius_m: float = 20.0
    clear_m: float = 25.0  # no building this close to a crossing street's centre
    deep_radius: float = 0.45  # segment kind by distance from the centre / half side (+ jitter)
    medium_radius: float = 1.0  # beyond: open (the corners of the square)
    kind_jitter: float = 0.15
    terrain_waves: int = 3
    terrain_wavelength_m: tuple[float, float] = (900.0, 2200.0)
    grade_per_wave: float = 0.016  # the waves' grades add up to at most 4.8 %
    kinds: dict[str, BuildingParams] = field(default_factory=_city_buildings)


@dataclass(frozen=True)
class Terrain:
    """Ground height z(E, N) = sum_k a_k sin(k_k . p + phi_k) - z(0, 0): smooth, zero at the origin."""

    amp: AnyArray  # (W,)
    kvec: AnyArray  # (W, 2) rad/m
    phase: AnyArray  # (W,)

    @classmethod
    def draw(cls, p: CityParams, rng: np.random.Generator) -> Terrain:
        lam = rng.uniform(*p.terrain_wavelength_m, size=p.terrain_waves)
        ang = rng.uniform(0.0, 2.0 * math.pi, size=p.terrain_waves)
        phase = rng.uniform(0.0, 2.0 * math.pi, size=p.terrain_waves)
        k = 2.0 * math.pi / lam
        return cls(p.grade_per_wave / k, np.stack([k * np.cos(ang), k * np.sin(ang)], axis=1), phase)

    def _arg(self, en: AnyArray) -> AnyArray:
        return np.asarray(en, dtype=float) @ self.kvec.T + self.phase

    def z(self, en: AnyArray) -> AnyArray:
        return np.sin(self._arg(en)) @ self.amp - float(np.sin(self.phase) @ self.amp)

    def gradient(self, en: AnyArray) -> AnyArray:
        """(..., 2) dz/dE, dz/dN."""
        return (np.cos(self._arg(en)) * self.amp) @ self.kvec

    def hessian_along(self, en: AnyArray, t: AnyArray) -> AnyArray:
        """t^T H t for unit plan directions t (..., 2): the terrain's curvature along t."""
        kt = np.asarray(t, dtype=float) @ self.kvec.T  # (..., W)
        return -(np.sin(self._arg(en)) * self.amp * kt * kt).sum(axis=-1)


class TerrainProfile(VerticalProfile):
    """A loop's vertical profile read off the city terrain under its centreline (exact z, grade,
    curvature), so every loop driving a street sees the same ground there."""

    def __init__(self, road: Road, terrain: Terrain) -> None:
        super().__init__(road.length_m, ())
        self.road = road
        self.terrain = terrain

    def z(self, s: AnyArray | float) -> AnyArray:
        p, _, _ = self.road.frame(s)
        return self.terrain.z(p)

    def grade(self, s: AnyArray | float) -> AnyArray:
        p, t, _ = self.road.frame(s)
        return (self.terrain.gradient(p) * t).sum(axis=-1)

    def curvature(self, s: AnyArray | float) -> AnyArray:
        """d(grade)/ds = t^T H t + kappa (grad z . left normal)."""
        p, t, k = self.road.frame(s)
        left = np.stack([-t[..., 1], t[..., 0]], axis=-1)
        return self.terrain.hessian_along(p, t) + k * (self.terrain.gradient(p) * left).sum(axis=-1)


@dataclass
class Street:
    """One street of the grid: along E at N = `at` (axis 0) or along N at E = `at` (axis 1).

    `cross` are the crossing streets' coordinates along it, `kinds` the section kind of each
    segment between them, `blocks[side]` its buildings (side +1 = north / east of the centre):
    rows of (u0, u1, height, setback from the street centre, depth, reflective).
    """

    axis: int
    at: float
    cross: AnyArray
    kinds: list[str]
    blocks: dict[int, AnyArray]


@dataclass(frozen=True)
class Platoon:
    """Vehicles `first` .. `first + size - 1`, on loop `loop`, front at `s_m`, speed `factor`."""

    first: int
    size: int
    loop: int
    s_m: float
    factor: float


@dataclass
class CityLayout:
    """The drawn city: street coordinates, streets, loop rectangles (grid indices), terrain."""

    xs: AnyArray  # E of the north-south streets, increasing
    ys: AnyArray  # N of the east-west streets
    streets: dict[tuple[int, int], Street]  # (axis, index)
    rects: list[tuple[int, int, int, int]]  # (west, east, south, north) street indices
    terrain: Terrain
    side_m: float


def city_side_m(p: CityParams, vehicles: int) -> float:
    """Side of the city for a fleet: density stays about that of 1000 vehicles in `side_at_1000_m`."""
    return float(np.clip(p.side_at_1000_m * math.sqrt(vehicles / 1000.0), *p.side_limits_m))


def _street_coords(p: CityParams, side: float, rng: np.random.Generator) -> AnyArray:
    """Street positions with varied spacing, shifted so the middle block is centred on the origin
    (where the base station stands, away from every street)."""
    n = max(2, round(side / float(np.mean(p.block_m))))
    xs = np.concatenate([[0.0], np.cumsum(rng.uniform(*p.block_m, size=n))])
    c = n // 2
    return xs - 0.5 * (xs[c] + xs[c + 1])


def _segment_kind(p: CityParams, mid: tuple[float, float], side: float, rng: np.random.Generator) -> str:
    """Deep canyons downtown, medium around them, open at the edge (with some randomness)."""
    r = math.hypot(*mid) / (side / 2.0) + rng.uniform(-p.kind_jitter, p.kind_jitter)
    return "deep" if r < p.deep_radius else "medium" if r < p.medium_radius else "open"


def _street_blocks(p: CityParams, cross: AnyArray, kinds: list[str], rng: np.random.Generator) -> AnyArray:
    """One side's buildings along a street, segment by segment, clear of every crossing."""
    rows: list[tuple[float, ...]] = []
    for a, b, kind in zip(cross[:-1], cross[1:], kinds, strict=True):
        bp = p.kinds.get(kind)
        u, end = a + p.clear_m, b - p.clear_m
        while bp is not None and u < end - 1.0:
            length = min(float(rng.uniform(*bp.block_m)), end - u)
            if rng.uniform() < bp.fill and length >= 4.0:
                h, w = float(rng.uniform(*bp.height_m)), float(rng.uniform(*bp.setback_m))
                rf = 1.0 if rng.uniform() < bp.reflective else 0.0
                rows.append((u, u + length, h, w, bp.depth_m, rf))
            u += length + float(rng.uniform(*bp.gap_m))
    return np.array(rows, dtype=float).reshape(-1, 6)


def _draw_rects(
    p: CityParams, n_loops: int, nx: int, ny: int, rng: np.random.Generator
) -> list[tuple[int, int, int, int]]:
    """Distinct rectangles of 1-4 x 1-4 blocks; they share streets and cross one another."""
    rects: list[tuple[int, int, int, int]] = []
    for _ in range(50 * n_loops):
        if len(rects) == n_loops:
            break
        wx = int(rng.integers(p.loop_blocks[0], min(p.loop_blocks[1], nx) + 1))
        wy = int(rng.integers(p.loop_blocks[0], min(p.loop_blocks[1], ny) + 1))
        a, c = int(rng.integers(0, nx - wx + 1)), int(rng.integers(0, ny - wy + 1))
        if (a, a + wx, c, c + wy) not in rects:
            rects.append((a, a + wx, c, c + wy))
    return rects


def platoon_sizes(p: CityParams, vehicles: int, rng: np.random.Generator) -> list[int]:
    """Sizes of 2-6 drawn until they add up to `vehicles` (the last one takes the remainder)."""
    sizes: list[int] = []
    left = vehicles
    while left > 0:
        k = min(int(rng.integers(p.platoon_size[0], p.platoon_size[1] + 1)), left)
        sizes.append(k)
        left -= k
    return sizes


def draw_layout(
    p: CityParams, vehicles: int, n_loops: int, rng: np.random.Generator, canyon_rng: np.random.Generator
) -> CityLayout:
    """Streets, their segment kinds and buildings, loop rectangles and the terrain."""
    side = city_side_m(p, vehicles)
    xs, ys = _street_coords(p, side, rng), _street_coords(p, side, rng)
    terrain = Terrain.draw(p, rng)
    streets: dict[tuple[int, int], Street] = {}
    for axis, coords, cross in ((0, ys, xs), (1, xs, ys)):
        for i, at in enumerate(coords):
            mids = [((u0 + u1) / 2.0, float(at)) for u0, u1 in itertools.pairwise(cross)]
            kinds = [_segment_kind(p, m if axis == 0 else (m[1], m[0]), side, rng) for m in mids]
            blocks = {sd: _street_blocks(p, cross, kinds, canyon_rng) for sd in (+1, -1)}
            streets[(axis, i)] = Street(axis, float(at), cross, kinds, blocks)
    rects = _draw_rects(p, n_loops, len(xs) - 1, len(ys) - 1, rng)
    return CityLayout(xs, ys, streets, rects, terrain, side)


def loop_waypoints(
    lay: CityLayout, rect: tuple[int, int, int, int], inset: float
) -> tuple[tuple[float, float], ...]:
    """Clockwise corners (right-hand traffic), `inset` inside the street centres; starts north-bound
    on the west street, so the legs run along streets west, north, east, south."""
    w, e, s, n = (
        lay.xs[rect[0]] + inset,
        lay.xs[rect[1]] - inset,
        lay.ys[rect[2]] + inset,
        lay.ys[rect[3]] - inset,
    )
    return ((w, s), (w, n), (e, n), (e, s))


def leg_streets(rect: tuple[int, int, int, int]) -> list[tuple[int, int]]:
    """(axis, index) of the street under each leg of `loop_waypoints`."""
    return [(1, rect[0]), (0, rect[3]), (1, rect[1]), (0, rect[2])]


def loop_spans(
    road: Road, lay: CityLayout, rect: tuple[int, int, int, int]
) -> tuple[tuple[tuple[float, str], ...], dict[int, AnyArray]]:
    """A loop's sections (start s, kind) and its building rows per side (s0, s1, h, setback, depth,
    reflective), mapped from the streets under its legs; turns keep the kind of the leg before."""
    spans: list[tuple[float, str]] = []
    rows: dict[int, list[AnyArray]] = {+1: [], -1: []}
    for (sa, sb), key in zip(road.legs(), leg_streets(rect), strict=True):
        st = lay.streets[key]
        along = np.eye(2)[st.axis]
        normal = np.eye(2)[1 - st.axis]
        p0, t0, _ = road.frame(np.array([sa]))
        u0, sgn = float(p0[0] @ along), float(np.sign(t0[0] @ along))
        offset = float(p0[0] @ normal) - st.at  # the loop's centreline from the street's
        left_is = float(np.sign(np.array([-t0[0, 1], t0[0, 0]]) @ normal))

        def to_s(u: AnyArray, sa: float = sa, u0: float = u0, sgn: float = sgn) -> AnyArray:
            return sa + (np.asarray(u) - u0) * sgn

        order = range(len(st.kinds)) if sgn > 0 else range(len(st.kinds) - 1, -1, -1)
        for i in order:
            lo, hi = sorted(to_s(np.array([st.cross[i], st.cross[i + 1]])))
            if min(hi, sb) - max(lo, sa) > 0.0:
                start = max(float(lo), sa)
                if not spans or spans[-1][1] != st.kinds[i]:
                    spans.append((start, st.kinds[i]))
        for side, blk in st.blocks.items():
            if len(blk) == 0:
                continue
            ends = np.sort(np.stack([to_s(blk[:, 0]), to_s(blk[:, 1])], axis=1), axis=1)
            s0, s1 = np.maximum(ends[:, 0], sa), np.minimum(ends[:, 1], sb)
            keep = s1 - s0 >= 4.0
            setback = blk[:, 3] - side * offset
            r = np.stack([s0, s1, blk[:, 2], setback, blk[:, 4], blk[:, 5]], axis=1)[keep]
            rows[int(side * left_is)].append(r)
    out = {}
    for side, parts in rows.items():
        r = np.concatenate(parts) if parts else np.zeros((0, 6))
        out[side] = r[np.argsort(r[:, 0], kind="stable")]
    return tuple(spans), out
