"""The fleet's solved positions, projected to the road surface, with a spatial index (eqs. 1-3).

Eq. (2) collects every vehicle's solution from the beginning to epoch t-1; eq. (3) keeps the ones
within `range_fitting` of the vehicle's SPP fix; Sec. 3.1 randomly down-selects to N_f,max. Each
position is stored already projected to the road by its vehicle's antenna height along the local up
at that point (eq. 1: p' = p - S [0, 0, h]), so later fits need no per-vehicle information.

Storage is bucketed in cubic ECEF cells of `cell_size_m` (frame-independent, no reference point to
choose, and a cell key is a natural unit for splitting the fleet into regions later, see
`cell_key`). A query visits the few cells that can hold points within range, so its cost does not
grow with the size of the fleet's history elsewhere. Memory is bounded by time (`max_history_s`)
and by `max_points_per_cell` (oldest dropped first).

Determinism: the candidates of a query are ordered by (time, vehicle id) before the random
down-selection, so the result depends only on the stored data and the Generator, not on insertion
order or on which cells were visited first.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from coplane.geo import up_vector
from coplane.plane.config import PlaneConfig
from coplane.typing import Vec

CellKey = tuple[int, int, int]

_R_MIN_M = 6.0e6  # a road vehicle's ECEF radius (Dead Sea shore to Everest with a wide margin)
_R_MAX_M = 6.6e6
_MAX_ANTENNA_M = 10.0


def cell_key(ecef: ArrayLike, cell_size_m: float) -> CellKey:
    """The cubic ECEF cell holding a point; regions can be defined as sets of these keys."""
    x, y, z = np.asarray(ecef, dtype=float).tolist()  # math.floor: np.floor's result, minus numpy's
    return (math.floor(x / cell_size_m), math.floor(y / cell_size_m), math.floor(z / cell_size_m))


def project_to_road(ecef: ArrayLike, antenna_height_m: float) -> Vec:
    """Eq. (1): move an antenna position down by its height along the local up at that point."""
    p = np.asarray(ecef, dtype=float)
    return np.asarray(p - antenna_height_m * up_vector(p), dtype=float)


def project_many_to_road(ecef: ArrayLike, antenna_heights_m: ArrayLike) -> Vec:
    """Eq. (1) for (N, 3) points at once (one vectorised geodetic conversion instead of N)."""
    p = np.asarray(ecef, dtype=float).reshape(-1, 3)
    h = np.broadcast_to(np.asarray(antenna_heights_m, dtype=float), (p.shape[0],))
    return np.asarray(p - h[:, None] * up_vector(p), dtype=float)


class _Bucket:
    """Growable column arrays of the points of one cell, in insertion order (serials increase)."""

    __slots__ = ("alive", "n", "n_alive", "serial", "sig", "t", "tkey", "vid", "xyz")

    def __init__(self, capacity: int = 8) -> None:
        self.t = np.empty(capacity)
        self.tkey = np.empty(capacity, dtype=np.int64)
        self.vid = np.empty(capacity, dtype=np.int32)
        self.serial = np.empty(capacity, dtype=np.int64)
        self.xyz = np.empty((capacity, 3))
        self.sig = np.empty(capacity)  # vertical 1-sigma of the solved position (NaN: unknown)
        self.alive = np.zeros(capacity, dtype=bool)
        self.n = 0
        self.n_alive = 0

    def append(self, t: float, tkey: int, vid: int, serial: int, xyz: Vec, sig: float = math.nan) -> None:
        if self.n == self.t.shape[0]:
            self._resize(max(8, 2 * self.n))
        i = self.n
        self.t[i], self.tkey[i], self.vid[i], self.serial[i], self.sig[i] = t, tkey, vid, serial, sig
        self.xyz[i] = xyz
        self.alive[i] = True
        self.n += 1
        self.n_alive += 1

    def kill(self, serial: int) -> None:
        i = int(np.searchsorted(self.serial[: self.n], serial))
        if i < self.n and self.serial[i] == serial and self.alive[i]:
            self.alive[i] = False
            self.n_alive -= 1

    def keep(self, mask: NDArray[np.bool_]) -> None:
        """Compact to the rows where `mask` (length n) is true; order (and serial order) is kept."""
        idx = np.flatnonzero(mask[: self.n])
        k = idx.shape[0]
        for name in ("t", "tkey", "vid", "serial", "xyz", "sig", "alive"):
            arr = getattr(self, name)
            arr[:k] = arr[idx]
        self.n = k
        self.n_alive = int(self.alive[:k].sum())
        if self.t.shape[0] > 64 and k < self.t.shape[0] // 4:
            self._resize(max(8, 2 * k))

    def _resize(self, capacity: int) -> None:
        for name in ("t", "tkey", "vid", "serial", "xyz", "sig", "alive"):
            old = getattr(self, name)
            new = np.zeros((capacity, *old.shape[1:]), dtype=old.dtype)
            new[: self.n] = old[: self.n]
            setattr(self, name, new)


@dataclass(frozen=True, eq=False)
class HistorySample:
    """Fitting points of one query with where they came from (for diagnostics and plots)."""

    points: Vec  # (N, 3) road-projected ECEF
    times_s: Vec  # (N,)
    vehicle_ids: tuple[str, ...]
    n_candidates: int  # points in range before the down-selection to n_max
    sigmas_up_m: Vec = field(default_factory=lambda: np.empty(0))  # (N,) vertical 1-sigma, NaN unknown


class PositionHistory:
    """All vehicles' road-projected solutions (eq. 2), queried by radius and time (eq. 3)."""

    def __init__(self, config: PlaneConfig | None = None) -> None:
        self.config = config or PlaneConfig()
        self._reset()

    def _reset(self) -> None:
        self._cells: dict[CellKey, _Bucket] = {}
        self._vids: list[str] = []
        self._vid_index: dict[str, int] = {}
        self._where: dict[tuple[int, int], tuple[CellKey, int]] = {}  # (vid, tkey) -> (cell, serial)
        self._serial = 0
        self._newest_s = -math.inf
        self._pruned_at_s = -math.inf
        self._rank: NDArray[np.int64] | None = None  # sort rank of each vehicle index by id

    # -- writing -----------------------------------------------------------------------------
    def add(
        self,
        vehicle_id: str,
        time_s: float,
        ecef: ArrayLike,
        antenna_height_m: float,
        sigma_up_m: float = math.nan,
    ) -> None:
        """Store a solved antenna position of `vehicle_id` at `time_s`, projected to the road (eq. 1).

        A second position of the same vehicle at the same epoch replaces the first (a fixed-lag
        smoother re-estimates past epochs). Implausible input raises ValueError.
        """
        p = self._check(vehicle_id, time_s, ecef, antenna_height_m)
        self._insert(vehicle_id, float(time_s), project_to_road(p, antenna_height_m), sigma_up_m)

    def add_many(
        self,
        vehicle_ids: Iterable[str],
        times_s: ArrayLike,
        ecef: ArrayLike,
        antenna_heights_m: ArrayLike,
        sigmas_up_m: ArrayLike | None = None,
    ) -> None:
        """`add` for many positions (e.g. one fleet solution) with one vectorised projection."""
        vids = list(vehicle_ids)
        p = np.asarray(ecef, dtype=float).reshape(-1, 3)
        t = np.broadcast_to(np.asarray(times_s, dtype=float), (p.shape[0],))
        h = np.broadcast_to(np.asarray(antenna_heights_m, dtype=float), (p.shape[0],))
        if len(vids) != p.shape[0]:
            raise ValueError(f"{len(vids)} vehicle ids for {p.shape[0]} positions")
        for i, vid in enumerate(vids):
            self._check(vid, float(t[i]), p[i], float(h[i]))
        road = project_many_to_road(p, h)
        sig = np.full(p.shape[0], math.nan) if sigmas_up_m is None else np.asarray(sigmas_up_m, dtype=float)
        for i, vid in enumerate(vids):
            self._insert(vid, float(t[i]), road[i], float(sig[i]))

    def prune(self, now_s: float | None = None) -> int:
        """Drop points older than `now_s - max_history_s` (default: newest time seen); returns count."""
        now = self._newest_s if now_s is None else float(now_s)
        if not math.isfinite(now):
            return 0
        cutoff = now - self.config.max_history_s
        removed = 0
        for key in list(self._cells):
            b = self._cells[key]
            old = b.t[: b.n] < cutoff
            if old.any():
                removed += int((old & b.alive[: b.n]).sum())
                self._forget(key, b, old)
                b.keep(~old & b.alive[: b.n])
            elif b.n - b.n_alive > b.n // 2:
                b.keep(b.alive[: b.n].copy())
            if b.n_alive == 0:
                del self._cells[key]
        self._pruned_at_s = now
        return removed

    def clear(self) -> None:
        self._reset()

    # -- reading -----------------------------------------------------------------------------
    def __len__(self) -> int:
        return sum(b.n_alive for b in self._cells.values())

    @property
    def vehicle_ids(self) -> tuple[str, ...]:
        return tuple(sorted(self._vids))

    @property
    def newest_time_s(self) -> float:
        return self._newest_s

    @property
    def n_cells(self) -> int:
        return len(self._cells)

    def select(
        self,
        center_ecef: ArrayLike,
        before_time_s: float,
        rng: np.random.Generator,
        vehicle_ids: Iterable[str] | None = None,
    ) -> Vec:
        """Eq. (3): road points within `range_fitting_m` of `center_ecef` (the SPP fix), from epochs
        strictly before `before_time_s` (and not older than `max_history_s`), down-selected at random
        to `n_max`. `vehicle_ids` restricts the source vehicles (e.g. only the vehicle itself)."""
        return self.select_records(center_ecef, before_time_s, rng, vehicle_ids).points

    def select_records(
        self,
        center_ecef: ArrayLike,
        before_time_s: float,
        rng: np.random.Generator,
        vehicle_ids: Iterable[str] | None = None,
        since_time_s: float = -math.inf,
    ) -> HistorySample:
        """`select` with the times and vehicle ids of the chosen points. Points older than
        `since_time_s` are left out: a vehicle that shares one history with others (the load
        generator's) sees only what it would have stored itself since it joined."""
        cfg = self.config
        c = np.asarray(center_ecef, dtype=float)
        if c.shape != (3,) or not np.isfinite(c).all():
            raise ValueError(f"center_ecef must be 3 finite numbers, got {center_ecef!r}")
        if not math.isfinite(before_time_s):
            raise ValueError(f"before_time_s is not finite: {before_time_s!r}")
        t_hi = before_time_s - cfg.time_tolerance_s
        t_lo = max(before_time_s - cfg.max_history_s, since_time_s)
        allowed: NDArray[np.int32] | None = None
        if vehicle_ids is not None:
            allowed = np.array(
                [self._vid_index[v] for v in set(vehicle_ids) if v in self._vid_index], dtype=np.int32
            )
        r = cfg.range_fitting_m
        buckets = self._buckets_near(c, r)
        if not buckets:
            return HistorySample(np.empty((0, 3)), np.empty(0), (), 0)
        # the few nearby cells' rows in one set of arrays: the filters below then cost a fixed
        # number of numpy calls per query instead of a dozen per cell
        t_all = np.concatenate([b.t[: b.n] for b in buckets])
        m = np.concatenate([b.alive[: b.n] for b in buckets]) & (t_all < t_hi) & (t_all >= t_lo)
        v_all = np.concatenate([b.vid[: b.n] for b in buckets])
        if allowed is not None:
            m &= np.isin(v_all, allowed)
        idx = np.flatnonzero(m)
        xyz = np.concatenate([b.xyz[: b.n] for b in buckets])
        diff = xyz[idx] - c
        idx = idx[np.einsum("ij,ij->i", diff, diff) < r * r]
        if not idx.size:
            return HistorySample(np.empty((0, 3)), np.empty(0), (), 0)
        v = v_all[idx]
        # by time, then vehicle id: independent of storage order
        order = np.lexsort((self._vehicle_rank()[v], t_all[idx]))
        n_cand = order.shape[0]
        if n_cand > cfg.n_max:
            order = order[np.sort(rng.choice(n_cand, size=cfg.n_max, replace=False))]
        rows = idx[order]
        vids = self._vids
        return HistorySample(
            points=xyz[rows],
            times_s=t_all[rows],
            vehicle_ids=tuple([vids[i] for i in v[order].tolist()]),
            n_candidates=n_cand,
            sigmas_up_m=np.concatenate([b.sig[: b.n] for b in buckets])[rows],
        )

    # -- internals ---------------------------------------------------------------------------
    def _check(self, vehicle_id: str, time_s: float, ecef: ArrayLike, antenna_height_m: float) -> Vec:
        """Reject implausible input. In Python scalars: a fleet solution's few points would spend
        more time in numpy's per-call overhead than in the checks."""
        p = np.asarray(ecef, dtype=float)
        if not isinstance(vehicle_id, str) or not vehicle_id:
            raise ValueError(f"vehicle_id must be a non-empty string, got {vehicle_id!r}")
        if not math.isfinite(time_s):
            raise ValueError(f"time of {vehicle_id} is not finite: {time_s!r}")
        xyz = p.tolist() if p.shape == (3,) else None
        if xyz is None or not all(math.isfinite(c) for c in xyz):
            raise ValueError(f"position of {vehicle_id} must be 3 finite numbers, got {ecef!r}")
        radius = math.hypot(*xyz)
        if not _R_MIN_M <= radius <= _R_MAX_M:
            raise ValueError(f"position of {vehicle_id} is {radius:.0f} m from the Earth's centre")
        if not (math.isfinite(antenna_height_m) and 0.0 <= antenna_height_m <= _MAX_ANTENNA_M):
            raise ValueError(f"antenna height of {vehicle_id} must be in [0, 10] m, got {antenna_height_m!r}")
        return p

    def _insert(self, vehicle_id: str, time_s: float, road: Vec, sigma_up_m: float = math.nan) -> None:
        cfg = self.config
        vid = self._vid_index.get(vehicle_id)
        if vid is None:
            vid = len(self._vids)
            self._vids.append(vehicle_id)
            self._vid_index[vehicle_id] = vid
            self._rank = None
        tkey = round(time_s / cfg.time_tolerance_s)
        old = self._where.pop((vid, tkey), None)
        if old is not None and old[0] in self._cells:
            self._cells[old[0]].kill(old[1])
        key = cell_key(road, cfg.cell_size_m)
        b = self._cells.get(key)
        if b is None:
            b = self._cells[key] = _Bucket()
        serial = self._serial
        self._serial += 1
        b.append(time_s, tkey, vid, serial, road, sigma_up_m)
        self._where[(vid, tkey)] = (key, serial)
        if b.n_alive > cfg.max_points_per_cell + cfg.max_points_per_cell // 4:
            self._cap(key, b)
        elif b.n - b.n_alive > max(32, b.n // 2):
            b.keep(b.alive[: b.n].copy())
        if time_s > self._newest_s:
            self._newest_s = time_s
            if time_s - self._pruned_at_s > cfg.max_history_s / 8.0:
                self.prune()

    def _vehicle_rank(self) -> NDArray[np.int64]:
        if self._rank is None or self._rank.shape[0] != len(self._vids):
            rank = np.empty(len(self._vids), dtype=np.int64)
            rank[np.argsort(np.array(self._vids, dtype=object))] = np.arange(len(self._vids))
            self._rank = rank
        return self._rank

    def _cap(self, key: CellKey, b: _Bucket) -> None:
        """Trim a cell to its newest `max_points_per_cell` points (ties: the later stored wins).

        Triggered at 1.25x the cap so that a full cell does not sort on every insertion."""
        n = b.n
        alive = np.flatnonzero(b.alive[:n])
        order = alive[np.lexsort((b.serial[alive], b.t[alive]))]  # oldest first
        drop = np.zeros(n, dtype=bool)
        drop[order[: alive.shape[0] - self.config.max_points_per_cell]] = True
        self._forget(key, b, drop)
        b.keep(b.alive[:n] & ~drop)

    def _forget(self, key: CellKey, b: _Bucket, rows: NDArray[np.bool_]) -> None:
        """Remove the replacement-index entries of the given rows (only if they point at them)."""
        for i in np.flatnonzero(rows[: b.n] & b.alive[: b.n]):
            k = (int(b.vid[i]), int(b.tkey[i]))
            if self._where.get(k) == (key, int(b.serial[i])):
                del self._where[k]

    def _buckets_near(self, c: Vec, r: float) -> list[_Bucket]:
        """Buckets of all cells that intersect the ball of radius r about c, in key order."""
        size = self.config.cell_size_m
        # math.floor on floats, as in cell_key: np.floor's result without numpy calls on a 3-vector
        x, y, z = float(c[0]), float(c[1]), float(c[2])
        lo = (math.floor((x - r) / size), math.floor((y - r) / size), math.floor((z - r) / size))
        hi = (math.floor((x + r) / size), math.floor((y + r) / size), math.floor((z + r) / size))
        n_cells = (hi[0] - lo[0] + 1) * (hi[1] - lo[1] + 1) * (hi[2] - lo[2] + 1)
        cells = self._cells
        if n_cells > len(cells):  # huge radius or tiny cells: scan what exists
            keys = sorted(k for k in cells if all(lo[j] <= k[j] <= hi[j] for j in range(3)))
        else:
            keys = [
                (i, j, k)
                for i in range(lo[0], hi[0] + 1)
                for j in range(lo[1], hi[1] + 1)
                for k in range(lo[2], hi[2] + 1)
                if (i, j, k) in cells
            ]
        return [cells[k] for k in keys]
