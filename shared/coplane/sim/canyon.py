"""Urban canyon: buildings along the road, an underpass deck, and per-satellite LOS / NLOS / blocked.

Model (a 2.5-D street canyon, the usual one in urban-GNSS simulation, e.g. Groves 2011,
"Shadow matching", J. Navigation 64(3); Bourdeau, Sahmoudi, Tourneret 2012):
* each straight leg has a row of building blocks on each side, generated per section kind with
  its own height, setback (facade distance from the road centreline), block length and gap
  ranges; intersections (the turns) are left open;
* a satellite ray is tested against the facade plane on the side it points to: horizontal
  distance D = d / |sin a| (d: perpendicular distance from the antenna to the facade, a: ray
  azimuth relative to the road heading), hit at along-road position s + D cos a; it is blocked
  when the block there is taller than the ray's height D tan(el) above the antenna;
* a blocked ray is received as NLOS when a specular reflection off the *opposite* facade exists
  (image method: the reflection point lies on a building, and the reflected ray clears the
  blocking row). Its extra path is 2 d' cos(el) |sin a| with d' the distance to the reflecting
  facade: always positive, metres to tens of metres, and smooth as the car and satellite move;
  otherwise the satellite is not tracked;
* the underpass deck blocks everything over its length; from outside, rays that hit the deck
  box (clearance + thickness) are blocked too; the cut on either side is walled by retaining
  walls as high as the road is deep.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from coplane.sim.road import SECTION_KINDS, Road, Sections
from coplane.typing import AnyArray

LOS, NLOS, BLOCKED = 0, 1, 2


@dataclass(frozen=True)
class BuildingParams:
    """Building rows of one section kind. Ranges are (low, high) for uniform draws."""

    height_m: tuple[float, float]
    setback_m: tuple[float, float]  # facade distance from the road centreline
    block_m: tuple[float, float] = (20.0, 60.0)
    gap_m: tuple[float, float] = (4.0, 20.0)
    fill: float = 0.9  # probability that a slot holds a building (else a gap of the same length)
    depth_m: float = 25.0  # footprint depth behind the facade (UWB blocking only)
    # share of facades smooth enough (glass, metal cladding) for a trackable specular reflection;
    # rough or broken facades scatter, and a blocked satellite is then simply lost
    reflective: float = 0.5


@dataclass(frozen=True)
class UnderpassParams:
    """The road passes under a bridge: clearance of the deck, its thickness and the cut walls."""

    clearance_m: float = 5.0
    deck_thickness_m: float = 1.5
    cut_setback_m: float = 5.5  # retaining wall distance from the centreline
    parapet_m: float = 1.0  # wall height above ground level
    approach_m: float = 170.0  # how far from the deck the cut is searched for


@dataclass(frozen=True)
class CanyonParams:
    kinds: dict[str, BuildingParams] = field(default_factory=dict)
    underpass: UnderpassParams = field(default_factory=UnderpassParams)
    corner_clear_m: float = 12.0  # no facade this close to the end of a leg (intersection)


@dataclass
class Visibility:
    """Result of `Canyon.visibility`: state, NLOS extra path (m) and the reflecting facade."""

    state: AnyArray  # int8: LOS, NLOS or BLOCKED
    excess_m: AnyArray  # > 0 exactly where NLOS
    reflect_setback_m: AnyArray  # setback of the facade the NLOS signal reflects off
    sign: AnyArray  # +1 when the direct ray goes to the left facade (reflection off the right one)


@dataclass
class _Row:
    s0: AnyArray
    s1: AnyArray
    height: AnyArray
    setback: AnyArray
    depth: AnyArray
    reflective: AnyArray


class Canyon:
    """Building rows, the underpass deck and the visibility test for a road and its sections."""

    def __init__(
        self, road: Road, sections: Sections, params: CanyonParams, rng: np.random.Generator
    ) -> None:
        self.road = road
        self.sections = sections
        self.params = params
        self._default_setback = np.array(
            [float(np.mean(params.kinds[k].setback_m)) if k in params.kinds else 30.0 for k in SECTION_KINDS]
        )
        self.decks = [(sec.s0, sec.s1) for sec in sections.sections if sec.kind == "underpass"]
        self.rows = {side: self._build_row(side, rng) for side in (+1, -1)}

    # --- construction ------------------------------------------------------------------------

    def _cut_depth(self, s: AnyArray) -> AnyArray:
        """How far the road lies below the surrounding ground near an underpass (0 elsewhere)."""
        prof = self.road.profile
        up = self.params.underpass
        depth = np.zeros_like(s)
        for d0, d1 in self.decks:
            a, b = d0 - up.approach_m, d1 + up.approach_m
            ground = max(float(prof.z(a)), float(prof.z(b)))
            m = np.mod(s - a, self.road.length_m) <= b - a
            depth = np.where(m, np.maximum(depth, ground - prof.z(s)), depth)
        return depth

    def _build_row(self, side: int, rng: np.random.Generator) -> _Row:
        s0s: list[float] = []
        s1s: list[float] = []
        hs: list[float] = []
        ws: list[float] = []
        ds: list[float] = []
        rf: list[float] = []
        up = self.params.underpass
        clear = self.params.corner_clear_m
        for a, b in self.road.legs():
            s = a + clear
            end = b - clear
            while s < end - 1.0:
                depth = float(self._cut_depth(np.array([s]))[0])
                kind = self.sections.kind(s)
                if kind == "underpass":
                    s += 2.0  # the deck itself is handled separately
                    continue
                if depth > 0.3:  # retaining wall of the cut, in 5 m panels
                    n = min(5.0, end - s)
                    mid = float(self._cut_depth(np.array([s + n / 2]))[0])
                    s0s.append(s)
                    s1s.append(s + n)
                    hs.append(mid + up.parapet_m)
                    ws.append(up.cut_setback_m)
                    ds.append(1.0)
                    rf.append(1.0)  # smooth concrete
                    s += n
                    continue
                p = self.params.kinds.get(kind)
                if p is None:
                    s += 5.0
                    continue
                length = float(rng.uniform(*p.block_m))
                # a block never runs into the next section or the cut
                nxt = min(end, self._next_boundary(s))
                length = min(length, nxt - s)
                if rng.uniform() < p.fill and length >= 4.0:
                    s0s.append(s)
                    s1s.append(s + length)
                    hs.append(float(rng.uniform(*p.height_m)))
                    ws.append(float(rng.uniform(*p.setback_m)))
                    ds.append(p.depth_m)
                    rf.append(1.0 if rng.uniform() < p.reflective else 0.0)
                s += length + float(rng.uniform(*p.gap_m))
        order = np.argsort(np.array(s0s))
        return _Row(*(np.asarray(v, dtype=float)[order] for v in (s0s, s1s, hs, ws, ds, rf)))

    def _next_boundary(self, s: float) -> float:
        for sec in self.sections.sections:
            if sec.s0 > s:
                return sec.s0
        return self.road.length_m

    # --- queries -----------------------------------------------------------------------------

    def facade(self, side: int, s: AnyArray) -> tuple[AnyArray, AnyArray, AnyArray]:
        """(height above road, setback, reflective) of the facade at along-road `s` on `side` (+1 left).

        Gaps return height 0, the section's default setback and not reflective.
        """
        row = self.rows[side]
        ss = np.mod(s, self.road.length_m)
        if len(row.s0) == 0:
            return np.zeros_like(ss), self._default_setback[self.sections.index(ss)], np.zeros(ss.shape, bool)
        i = np.searchsorted(row.s0, ss, side="right") - 1
        ic = np.clip(i, 0, len(row.s0) - 1)
        inside = (i >= 0) & (ss < row.s1[ic])
        h = np.where(inside, row.height[ic], 0.0)
        w = np.where(inside, row.setback[ic], self._default_setback[self.sections.index(ss)])
        return h, w, inside & (row.reflective[ic] > 0.5)

    def _facade_lookup(self, left: AnyArray, s: AnyArray) -> tuple[AnyArray, AnyArray]:
        hl, wl, _ = self.facade(+1, s)
        hr, wr, _ = self.facade(-1, s)
        return np.where(left, hl, hr), np.where(left, wl, wr)

    def _reflective(self, left: AnyArray, s: AnyArray) -> AnyArray:
        return np.where(left, self.facade(+1, s)[2], self.facade(-1, s)[2])

    def visibility(
        self,
        s: AnyArray,
        y: AnyArray,
        h_ant: AnyArray,
        heading: AnyArray,
        az: AnyArray,
        el: AnyArray,
    ) -> Visibility:
        """State (LOS / NLOS / BLOCKED) and NLOS extra path per (receiver, satellite).

        s, y, h_ant: (N,) along-road position, lateral offset (+ left), antenna height;
        heading: (N, 2) unit East-North direction of travel; az, el: (N, S) radians
        (N may be a flattened list of receiver-satellite pairs with S = 1).
        """
        s2 = np.asarray(s, dtype=float)[:, None]
        y2 = np.asarray(y, dtype=float)[:, None]
        h2 = np.asarray(h_ant, dtype=float)[:, None]
        te, tn = heading[:, 0:1], heading[:, 1:2]
        ue, un = np.sin(az), np.cos(az)
        cos_a = ue * te + un * tn
        sin_a = ue * (-tn) + un * te  # component toward the left side
        tan_el = np.tan(np.clip(el, -1.5, 1.5))
        abs_sin = np.maximum(np.abs(sin_a), 1e-6)
        to_left = sin_a > 0.0
        sign = np.where(to_left, 1.0, -1.0)
        shape = np.broadcast_shapes(s2.shape, az.shape)
        s_b = np.broadcast_to(s2, shape)

        # blocking facade (the side the ray points to): iterate once for the setback at the hit
        _, w = self._facade_lookup(to_left, s_b)
        for _ in range(2):
            d = np.maximum(w - sign * y2, 0.5)
            dist = d / abs_sin
            s_hit = s_b + dist * cos_a
            h_bld, w = self._facade_lookup(to_left, s_hit)
        d = np.maximum(w - sign * y2, 0.5)
        dist = d / abs_sin
        s_hit = s_b + dist * cos_a
        h_bld, _ = self._facade_lookup(to_left, s_hit)
        direct_blocked = (h_bld - h2 > dist * tan_el) & (np.abs(sin_a) > 1e-3)

        # reflection off the opposite facade (image method)
        opp = ~to_left
        _, w_o = self._facade_lookup(opp, s_b)
        for _ in range(2):
            d_o = np.maximum(w_o + sign * y2, 0.5)
            dist_o = d_o / abs_sin
            s_ref = s_b + dist_o * cos_a
            h_ref_bld, w_o = self._facade_lookup(opp, s_ref)
        d_o = np.maximum(w_o + sign * y2, 0.5)
        dist_o = d_o / abs_sin
        s_ref = s_b + dist_o * cos_a
        h_ref_bld, _ = self._facade_lookup(opp, s_ref)
        z_ref = dist_o * tan_el  # above the antenna
        on_wall = (h_ref_bld - h2 > z_ref) & self._reflective(opp, s_ref)
        width = w_o + w
        dist_x = width / abs_sin
        s_x = s_ref + dist_x * cos_a
        h_x, _ = self._facade_lookup(to_left, s_x)
        clears = z_ref + dist_x * tan_el > h_x - h2
        extra = 2.0 * d_o * np.cos(el) * np.abs(sin_a)

        state = np.full(shape, LOS, dtype=np.int8)
        nlos = direct_blocked & on_wall & clears & (el > 0.0)
        state[direct_blocked] = BLOCKED
        state[nlos] = NLOS
        state[el <= 0.0] = BLOCKED

        # underpass deck
        if self.decks:
            deck_blocked = self._deck_blocks(s_b, h2, cos_a, tan_el)
            state[deck_blocked] = BLOCKED
        excess = np.where(state == NLOS, extra, 0.0)
        return Visibility(
            state, excess, np.broadcast_to(w_o, shape).copy(), np.broadcast_to(sign, shape).copy()
        )

    @staticmethod
    def reflection_extra(
        setback: AnyArray, sign: AnyArray, y: AnyArray, heading: AnyArray, az: AnyArray, el: AnyArray
    ) -> AnyArray:
        """Extra path 2 d cos(el) |sin a| of a reflection off the facade at `setback` on the side
        opposite to `sign` (+1: ray toward the left, reflection off the right facade).

        Used with the facade frozen to differentiate the NLOS bias in time (its Doppler error).
        """
        te, tn = heading[..., 0], heading[..., 1]
        sin_a = np.sin(az) * (-tn) + np.cos(az) * te
        d = np.maximum(setback + sign * y, 0.5)
        return 2.0 * d * np.cos(el) * np.abs(sin_a)

    def _deck_blocks(self, s_b: AnyArray, h2: AnyArray, cos_a: AnyArray, tan_el: AnyArray) -> AnyArray:
        up = self.params.underpass
        prof = self.road.profile
        length = self.road.length_m
        out = np.zeros(s_b.shape, dtype=bool)
        z_ant = prof.z(s_b) + h2
        for d0, d1 in self.decks:
            z_under = float(prof.z(0.5 * (d0 + d1))) + up.clearance_m
            z_top = z_under + up.deck_thickness_m
            rel0 = np.mod(s_b - d0 + length / 2, length) - length / 2  # s relative to the deck start
            span = d1 - d0
            under = (rel0 >= 0.0) & (rel0 <= span)
            out |= under
            near = ~under & (np.abs(rel0) < 200.0) | ~under & (np.abs(rel0 - span) < 200.0)
            if not np.any(near):
                continue
            ahead = rel0 < 0.0  # deck in front of the antenna
            toward = np.where(ahead, cos_a > 0.0, cos_a < 0.0)
            d_near = np.where(ahead, -rel0, rel0 - span)
            d_far = d_near + span
            ac = np.maximum(np.abs(cos_a), 1e-6)
            z_in = z_ant + d_near / ac * tan_el
            z_out = z_ant + d_far / ac * tan_el
            hits = (z_in <= z_top) & (z_out >= z_under)
            out |= near & toward & hits
        return out

    # --- plan-view footprints (UWB blocking) -------------------------------------------------

    def footprint_grid(self, cell_m: float = 2.0) -> FootprintGrid:
        """Rasterised building footprints (and cut walls) in the local East-North frame."""
        pts: list[AnyArray] = []
        for side, row in self.rows.items():
            for s0, s1, w, dep in zip(row.s0, row.s1, row.setback, row.depth, strict=True):
                ss = np.arange(s0, s1 + 1e-9, cell_m / 2.0)
                ys = np.arange(w, w + dep + 1e-9, cell_m / 2.0) * side
                sg, yg = np.meshgrid(ss, ys, indexing="ij")
                pts.append(self.road.plan_point(sg.ravel(), yg.ravel()))
        allp = np.concatenate(pts) if pts else np.zeros((0, 2))
        return FootprintGrid.from_points(allp, cell_m)


@dataclass
class FootprintGrid:
    origin: AnyArray
    cell_m: float
    occupied: AnyArray  # bool (nx, ny)

    @classmethod
    def from_points(cls, pts: AnyArray, cell_m: float) -> FootprintGrid:
        if len(pts) == 0:
            return cls(np.zeros(2), cell_m, np.zeros((1, 1), dtype=bool))
        lo = pts.min(axis=0) - 2 * cell_m
        hi = pts.max(axis=0) + 2 * cell_m
        n = np.ceil((hi - lo) / cell_m).astype(int) + 1
        occ = np.zeros((int(n[0]), int(n[1])), dtype=bool)
        ij = np.floor((pts - lo) / cell_m).astype(int)
        occ[ij[:, 0], ij[:, 1]] = True
        return cls(lo, cell_m, occ)

    def blocked(self, a: AnyArray, b: AnyArray, step_m: float = 3.0) -> AnyArray:
        """Whether the plan-view segment a -> b ((P, 2) each) crosses a footprint."""
        a = np.asarray(a, dtype=float)
        b = np.asarray(b, dtype=float)
        if len(a) == 0:
            return np.zeros(0, dtype=bool)
        length = np.linalg.norm(b - a, axis=1)
        n = max(2, math.ceil(float(length.max()) / step_m) + 1)
        f = np.linspace(0.0, 1.0, n)[1:-1]
        p = a[:, None, :] + (b - a)[:, None, :] * f[None, :, None]
        ij = np.floor((p - self.origin) / self.cell_m).astype(int)
        nx, ny = self.occupied.shape
        ok = (ij[..., 0] >= 0) & (ij[..., 0] < nx) & (ij[..., 1] >= 0) & (ij[..., 1] < ny)
        occ = np.zeros(ok.shape, dtype=bool)
        occ[ok] = self.occupied[ij[..., 0][ok], ij[..., 1][ok]]
        return np.asarray(occ.any(axis=1))
