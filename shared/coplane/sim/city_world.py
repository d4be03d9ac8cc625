"""The city as one road, one set of sections and one canyon, so the per-epoch code runs unchanged.

The per-epoch code (coplane.sim.visibility, epoch, injection) reads a vehicle's along-road
position `track.s` and asks `world.road` and `world.canyon` about it. The city's loops are laid
end to end on one arc-length axis: loop i occupies [i * SPAN_M, i * SPAN_M + L_i), and the
classes here decode a position into (loop, s on that loop) and ask the loop's own Road, Sections
or Canyon (built by the existing machinery from coplane.sim.city's street map). Motion is
simulated per loop with coplane.sim.motion (each loop gets its own seeded stream) and the tracks
are put together in vehicle order. See docs/simulator.md (City).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from coplane.sim.canyon import Canyon, CanyonParams, FootprintGrid, Visibility, _Row
from coplane.sim.city import (
    CityLayout,
    CityParams,
    Platoon,
    TerrainProfile,
    draw_layout,
    loop_spans,
    loop_waypoints,
    platoon_sizes,
)
from coplane.sim.errors import component_rng
from coplane.sim.motion import FleetStart, FleetTrack, simulate_motion
from coplane.sim.road import Road, Section, Sections
from coplane.sim.scenarios import Scenario
from coplane.typing import AnyArray

SPAN_M = 100_000.0  # arc-length room per loop on the city axis (loops are a few km)


def _decode(s: AnyArray | float, lengths: AnyArray) -> tuple[AnyArray, AnyArray]:
    """(loop index, s on the loop) of city-axis positions; a quarter span of slack either side."""
    ss = np.asarray(s, dtype=float)
    loop = np.clip(np.floor(ss / SPAN_M + 0.25).astype(int), 0, len(lengths) - 1)
    return loop, np.mod(ss - loop * SPAN_M, lengths[loop])


class _LoopCanyon(Canyon):
    """A loop's canyon whose building rows come from the city's streets instead of its own draws."""

    def __init__(
        self, road: Road, sections: Sections, params: CanyonParams, rows: dict[int, AnyArray]
    ) -> None:
        self._given = {side: _Row(*(r[:, c].copy() for c in range(6))) for side, r in rows.items()}
        super().__init__(road, sections, params, np.random.default_rng(0))

    def _build_row(self, side: int, rng: np.random.Generator) -> _Row:
        return self._given[side]


class CityRoad(Road):
    """Every loop of the city on one axis (see the module docstring); lanes as on each loop."""

    def __init__(self, loops: list[Road]) -> None:  # not Road.__init__: no centreline of its own
        self.loops = loops
        self.lanes, self.lane_width_m = loops[0].lanes, loops[0].lane_width_m
        self.lengths = np.array([r.length_m for r in loops])
        self.length_m = SPAN_M * len(loops)
        off = [i * SPAN_M for i in range(len(loops))]
        self._legs = [(o + a, o + b) for o, r in zip(off, loops, strict=True) for a, b in r.legs()]
        self._turns = [(o + a, o + b, d) for o, r in zip(off, loops, strict=True) for a, b, d in r.turns()]
        self.profile = _CityProfile(self)

    def frame(self, s: AnyArray | float) -> tuple[AnyArray, AnyArray, AnyArray]:
        """Road.frame of the loop under each city-axis position."""
        loop, local = _decode(s, self.lengths)
        p, t, k = np.zeros((*local.shape, 2)), np.zeros((*local.shape, 2)), np.zeros(local.shape)
        for i in np.unique(loop).tolist():
            m = loop == i
            p[m], t[m], k[m] = self.loops[i].frame(local[m])
        return p, t, k


class _CityProfile(TerrainProfile):
    """The terrain under the city axis (every loop samples the same terrain)."""

    def __init__(self, road: CityRoad) -> None:
        terrain = road.loops[0].profile
        assert isinstance(terrain, TerrainProfile)
        super().__init__(road, terrain.terrain)


class CitySections(Sections):
    """Every loop's sections on the city axis."""

    def __init__(self, road: CityRoad, loops: list[Sections]) -> None:
        spans = [(i * SPAN_M + sec.s0, sec.kind) for i, ls in enumerate(loops) for sec in ls.sections]
        super().__init__(road.length_m, tuple(spans))
        self.lengths = road.lengths
        self.sections = tuple(
            Section(i * SPAN_M + sec.s0, i * SPAN_M + sec.s1, sec.kind)
            for i, ls in enumerate(loops)
            for sec in ls.sections
        )

    def index(self, s: AnyArray | float) -> AnyArray:
        """Section kind index; past a loop's end wraps to that loop's start, not the next loop."""
        loop, local = _decode(s, self.lengths)
        return super().index(loop * SPAN_M + local)


class CityCanyon(Canyon):
    """Each vehicle sees its own loop's canyon; UWB sees every building of the city."""

    def __init__(
        self,
        road: CityRoad,
        sections: CitySections,
        params: CanyonParams,
        loops: list[Canyon],
        grid: FootprintGrid,
    ) -> None:  # not Canyon.__init__: the buildings are the loops'
        self.road, self.sections, self.params = road, sections, params
        self.loops, self.grid = loops, grid
        self.lengths = road.lengths
        self.decks = []
        self.rows = {}

    def visibility(
        self, s: AnyArray, y: AnyArray, h_ant: AnyArray, heading: AnyArray, az: AnyArray, el: AnyArray
    ) -> Visibility:
        """Canyon.visibility, each vehicle against its own loop's canyon (s on the city axis)."""
        loop, local = _decode(s, self.lengths)
        shape = np.broadcast_shapes(local[:, None].shape, az.shape)
        state = np.zeros(shape, dtype=np.int8)
        excess, setback, sign = np.zeros(shape), np.zeros(shape), np.zeros(shape)
        for i in np.unique(loop).tolist():
            m = loop == i
            v = self.loops[i].visibility(
                local[m], np.asarray(y)[m], np.asarray(h_ant)[m], heading[m], az[m], el[m]
            )
            state[m], excess[m], setback[m], sign[m] = v.state, v.excess_m, v.reflect_setback_m, v.sign
        return Visibility(state, excess, setback, sign)

    def facade(self, side: int, s: AnyArray) -> tuple[AnyArray, AnyArray, AnyArray]:
        """Canyon.facade of the loop under each city-axis position."""
        loop, local = _decode(s, self.lengths)
        h, w, r = np.zeros(local.shape), np.zeros(local.shape), np.zeros(local.shape, bool)
        for i in np.unique(loop).tolist():
            m = loop == i
            h[m], w[m], r[m] = self.loops[i].facade(side, local[m])
        return h, w, r

    def footprint_grid(self, cell_m: float = 2.0) -> FootprintGrid:
        """The whole city's buildings (rasterised once from the street map, see `footprints`)."""
        return self.grid


def footprints(lay: CityLayout, cell_m: float = 2.0) -> FootprintGrid:
    """Every building of the city rasterised in plan (streets are straight: rectangles)."""
    half = lay.side_m / 2.0 + 400.0
    lo = np.array([min(lay.xs[0], -half), min(lay.ys[0], -half)]) - 100.0
    hi = np.array([max(lay.xs[-1], half), max(lay.ys[-1], half)]) + 100.0
    n = np.ceil((hi - lo) / cell_m).astype(int) + 1
    occ = np.zeros((int(n[0]), int(n[1])), dtype=bool)
    for st in lay.streets.values():
        for side, blk in st.blocks.items():
            for u0, u1, _, w, dep, _ in blk:
                a, b = sorted((st.at + side * w, st.at + side * (w + dep)))
                e0, e1, n0, n1 = (u0, u1, a, b) if st.axis == 0 else (a, b, u0, u1)
                i0, i1 = int((e0 - lo[0]) // cell_m), int((e1 - lo[0]) // cell_m) + 1
                j0, j1 = int((n0 - lo[1]) // cell_m), int((n1 - lo[1]) // cell_m) + 1
                occ[i0:i1, j0:j1] = True
    return FootprintGrid(lo, cell_m, occ)


@dataclass
class City:
    """What build_city returns to coplane.sim.world."""

    layout: CityLayout
    platoons: list[Platoon]
    road: CityRoad
    sections: CitySections
    canyon: CityCanyon
    track: FleetTrack


def _place_platoons(
    p: CityParams, sizes: list[int], lengths: AnyArray, lanes: int, rng: np.random.Generator
) -> list[Platoon]:
    """Loop per platoon (first one per loop, then in proportion to loop length) and start positions
    spread around each loop so that platoons on one loop do not start on top of each other."""
    n = len(lengths)
    loops = [i if i < n else int(rng.choice(n, p=lengths / lengths.sum())) for i in range(len(sizes))]
    factor = rng.uniform(*p.platoon_factor, size=len(sizes))
    first = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(int)
    s_front = np.zeros(len(sizes))
    for li in range(n):
        members = [k for k, lp in enumerate(loops) if lp == li]
        slot = lengths[li] / max(len(members), 1)
        s0 = rng.uniform(0.0, lengths[li])
        for j, k in enumerate(members):
            length = 45.0 * math.ceil(sizes[k] / lanes)  # a platoon's length, with its gaps
            s_front[k] = s0 + j * slot + rng.uniform(0.0, max(0.0, slot - length - 30.0))
    return [
        Platoon(int(first[k]), sizes[k], loops[k], float(s_front[k]), float(factor[k]))
        for k in range(len(sizes))
    ]


def _fleet_start(p: CityParams, platoons: list[Platoon], lanes: int, rng: np.random.Generator) -> FleetStart:
    """Platoon members: lanes alternate, each a gap behind the one ahead in its lane."""
    s, convoy, factor = [], [], []
    for c, q in enumerate(platoons):
        gaps = rng.uniform(*p.platoon_gap_m, size=q.size)
        for j in range(q.size):
            rank = j // lanes
            s.append(q.s_m - float(np.sum(gaps[:rank] + 4.5)) - (j % lanes) * 6.0)
            convoy.append(c)
            factor.append(q.factor + rng.uniform(-1.0, 1.0) * p.member_factor_spread)
    return FleetStart(np.array(s), np.array(convoy), np.array(factor))


def _merge_tracks(
    parts: list[tuple[AnyArray, FleetTrack]], vehicles: int, offsets: list[float]
) -> FleetTrack:
    """One FleetTrack in vehicle order from per-loop tracks (s moved onto the city axis)."""
    first = parts[0][1]
    k = len(first.times_s)

    def cat(name: str, extra: tuple[int, ...] = ()) -> AnyArray:
        out = np.zeros((k, vehicles, *extra), dtype=getattr(first, name).dtype)
        for idx, tr in parts:
            out[:, idx] = getattr(tr, name)
        return out

    s = cat("s")
    for (idx, _), off in zip(parts, offsets, strict=True):
        s[:, idx] += off
    h = np.zeros(vehicles)
    for idx, tr in parts:
        h[idx] = tr.antenna_height_m
    return FleetTrack(
        ids=[f"u{i + 1}" for i in range(vehicles)],
        times_s=first.times_s,
        s=s,
        y=cat("y"),
        speed=cat("speed"),
        s_rate=cat("s_rate"),
        y_rate=cat("y_rate"),
        lane=cat("lane"),
        antenna_height_m=h,
        enu=cat("enu", (3,)),
        ecef=cat("ecef", (3,)),
        vel_ecef=cat("vel_ecef", (3,)),
        heading=cat("heading", (2,)),
        section=cat("section"),
    )


def build_city(sc: Scenario, vehicles: int, n_epochs: int, seed: int) -> City:
    """Lay out the city for `vehicles` and drive every platoon on its loop (seeded streams)."""
    p, rp = sc.city, sc.road
    if p is None:
        raise ValueError(f"scenario {sc.name!r} has no city")
    rng = component_rng(seed, "city")
    sizes = platoon_sizes(p, vehicles, rng)
    n_loops = max(1, min(len(sizes), max(p.min_loops, round(vehicles / p.vehicles_per_loop))))
    lay = draw_layout(p, vehicles, n_loops, rng, component_rng(seed, "city-canyon"))
    inset = rp.lanes * rp.lane_width_m / 2.0  # the loop drives the right-hand carriageway
    params = CanyonParams(kinds=p.kinds)
    roads: list[Road] = []
    secs: list[Sections] = []
    canyons: list[Canyon] = []
    for rect in lay.rects:
        road = Road(loop_waypoints(lay, rect, inset), p.corner_radius_m, rp.lanes, rp.lane_width_m)
        road.profile = TerrainProfile(road, lay.terrain)
        spans, rows = loop_spans(road, lay, rect)
        sec = Sections(road.length_m, spans)
        roads.append(road)
        secs.append(sec)
        canyons.append(_LoopCanyon(road, sec, params, rows))
    city_road = CityRoad(roads)
    platoons = _place_platoons(p, sizes, city_road.lengths, rp.lanes, rng)
    origin = (rp.origin_lat_deg, rp.origin_lon_deg, rp.origin_h_m)
    parts: list[tuple[AnyArray, FleetTrack]] = []
    offsets: list[float] = []
    for li, road in enumerate(roads):
        mine = [q for q in platoons if q.loop == li]
        if not mine:
            continue
        idx = np.concatenate([np.arange(q.first, q.first + q.size) for q in mine])
        start = _fleet_start(p, mine, rp.lanes, rng)
        tr = simulate_motion(
            road,
            secs[li],
            sc.motion,
            len(idx),
            n_epochs,
            sc.interval_s,
            origin,
            component_rng(seed, "motion", li),
            start,
        )
        parts.append((idx, tr))
        offsets.append(li * SPAN_M)
    sections = CitySections(city_road, secs)
    canyon = CityCanyon(city_road, sections, params, canyons, footprints(lay))
    return City(lay, platoons, city_road, sections, canyon, _merge_tracks(parts, vehicles, offsets))
