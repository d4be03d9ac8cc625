"""Inter-vehicle UWB ranging: two-way ranges with noise, NLOS bias, burst dropouts and a range limit.

* noise: 0.3 m (1 sigma), the value the paper takes from its UWB data sheet (Sec. IV, [38]);
* nothing beyond 500 m (the paper's sensors' maximum range), and a loss probability that rises
  from `fade_start_m` to the limit as the link budget runs out;
* NLOS: when a third vehicle's body is close to the line between two antennas, the first path is
  attenuated and the range is biased long by 0.2-1.5 m (DW1000-class radios; Dardari et al.
  2009, Proc. IEEE 97(2) report tens of cm to metres); when a building footprint cuts the line
  (around a corner) the range is usually lost and, if not, biased by metres;
* dropouts come in bursts: each pair is a Gilbert-Elliott two-state channel (Gilbert 1960,
  Bell Syst. Tech. J. 39; Elliott 1963), the usual model of packet-loss bursts in V2V links;
* each vehicle ranges only with its `max_neighbours` nearest vehicles in range (a TDMA ranging
  schedule cannot serve everyone at 1 Hz); with 4 vehicles that is every pair.

Fleets above DENSE_MAX_VEHICLES (the city's 1000+) find neighbours and blocking vehicles with a
k-d tree instead of all-pairs arrays: the same pairs and flags (to rounding ties), in a fraction
of the time; smaller fleets keep the all-pairs code, so their recordings stay byte for byte.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from coplane.sim.canyon import FootprintGrid
from coplane.typing import AnyArray

DENSE_MAX_VEHICLES = 300


@dataclass(frozen=True)
class UwbParams:
    sigma_m: float = 0.3
    max_range_m: float = 500.0
    fade_start_m: float = 350.0
    max_neighbours: int = 12
    body_radius_m: float = 1.2  # a vehicle this close to the line blocks it
    body_bias_m: tuple[float, float] = (0.2, 1.5)
    body_extra_sigma_m: float = 0.2
    building_loss: float = 0.8
    building_bias_mean_m: float = 3.0
    ge_good_to_bad: float = 0.03  # per epoch
    ge_bad_to_good: float = 0.25
    ge_loss_good: float = 0.02
    ge_loss_bad: float = 0.9


@dataclass
class UwbEpoch:
    """Ranges of one epoch: index pairs (i < j), measured range and truth/diagnostics."""

    i: AnyArray
    j: AnyArray
    range_m: AnyArray
    true_m: AnyArray
    nlos: AnyArray  # 0 LOS, 1 vehicle body, 2 building


class UwbSimulator:
    """Per-epoch UWB measurements for a fleet; the Gilbert-Elliott state persists per pair."""

    def __init__(
        self, n: int, params: UwbParams, grid: FootprintGrid | None, rng: np.random.Generator
    ) -> None:
        self.n = n
        self.p = params
        self.grid = grid
        self.rng = rng
        self.bad = np.zeros((n, n), dtype=bool)  # channel state per pair (upper triangle used)

    def _candidate_pairs(self, pos: AnyArray, tree: cKDTree | None) -> tuple[AnyArray, AnyArray, AnyArray]:
        n = self.n
        if tree is not None:
            return self._tree_pairs(pos, tree)
        d = np.linalg.norm(pos[:, None, :] - pos[None, :, :], axis=-1)
        np.fill_diagonal(d, np.inf)
        k = min(self.p.max_neighbours, n - 1)
        near = np.zeros((n, n), dtype=bool)
        if k > 0:
            idx = np.argsort(d, axis=1, kind="stable")[:, :k]
            near[np.arange(n)[:, None], idx] = True
        near = (near | near.T) & (d <= self.p.max_range_m)
        i, j = np.nonzero(np.triu(near, 1))
        return i, j, d[i, j]

    def _tree_pairs(self, pos: AnyArray, tree: cKDTree) -> tuple[AnyArray, AnyArray, AnyArray]:
        """`_candidate_pairs` for big fleets: each vehicle's k nearest within range from a k-d tree
        (exact distances recomputed as the all-pairs code does), pairs in the same (i, j) order."""
        n, k = self.n, min(self.p.max_neighbours, self.n - 1)
        _, idx = tree.query(pos, k=k + 1, distance_upper_bound=self.p.max_range_m * 1.001)
        rows = np.repeat(np.arange(n), k + 1)
        cols = idx.ravel()
        ok = (cols < n) & (cols != rows)
        rows, cols = rows[ok], cols[ok]
        # self may sit anywhere in the list if positions coincide: keep the first k others per row
        rank = np.arange(len(rows)) - np.searchsorted(rows, rows)
        rows, cols = rows[rank < k], cols[rank < k]
        key = np.unique(np.minimum(rows, cols) * n + np.maximum(rows, cols))
        i, j = key // n, key % n
        d = np.linalg.norm(pos[i] - pos[j], axis=-1)
        keep = d <= self.p.max_range_m
        return i[keep], j[keep], d[keep]

    def _body_blocked(self, pos: AnyArray, i: AnyArray, j: AnyArray, tree: cKDTree | None) -> AnyArray:
        """Whether a third vehicle is within `body_radius_m` of each pair's line of sight."""
        p, n, m = self.p, self.n, len(i)
        a, b = pos[i], pos[j]
        ab = b - a
        ll = np.maximum(np.einsum("pk,pk->p", ab, ab), 1e-9)
        body = np.zeros(m, dtype=bool)
        if tree is not None:  # only vehicles in the ball around the segment can block it
            near = tree.query_ball_point((a + b) / 2.0, np.sqrt(ll) / 2.0 + p.body_radius_m)
            counts = np.array([len(c) for c in near])
            pair = np.repeat(np.arange(m), counts)
            veh = np.concatenate([np.asarray(c, dtype=np.intp) for c in near]) if m else np.zeros(0, np.intp)
            rel = pos[veh] - a[pair]
            tpar = np.einsum("pk,pk->p", rel, ab[pair]) / ll[pair]
            dd = np.linalg.norm(pos[veh] - (a[pair] + tpar[:, None] * ab[pair]), axis=-1)
            inside = (
                (tpar > 0.0) & (tpar < 1.0) & (dd < p.body_radius_m) & (veh != i[pair]) & (veh != j[pair])
            )
            body[pair[inside]] = True
            return body
        chunk = max(1, 2_000_000 // max(n, 1))
        for c0 in range(0, m, chunk):
            sl = slice(c0, c0 + chunk)
            rel = pos[None, :, :] - a[sl, None, :]
            tpar = np.einsum("pnk,pk->pn", rel, ab[sl]) / ll[sl, None]
            closest = a[sl, None, :] + tpar[..., None] * ab[sl, None, :]
            dd = np.linalg.norm(pos[None, :, :] - closest, axis=-1)
            inside = (tpar > 0.0) & (tpar < 1.0) & (dd < p.body_radius_m)
            inside[np.arange(inside.shape[0]), i[sl]] = False
            inside[np.arange(inside.shape[0]), j[sl]] = False
            body[sl] = inside.any(axis=1)
        return body

    def step(self, pos_ecef: AnyArray, plan_en: AnyArray) -> UwbEpoch:
        """One epoch from antenna positions (N, 3) ECEF and their plan-view East-North (N, 2)."""
        p, rng = self.p, self.rng
        n = self.n
        # channel state evolves for every pair every epoch (fixed draw count: reproducible)
        u = rng.uniform(size=(n, n))
        self.bad = np.where(self.bad, u >= p.ge_bad_to_good, u < p.ge_good_to_bad)
        tree = cKDTree(pos_ecef) if n > DENSE_MAX_VEHICLES else None
        i, j, dist = self._candidate_pairs(pos_ecef, tree)
        m = len(i)
        noise = rng.standard_normal(m)
        u_loss = rng.uniform(size=m)
        u_bias = rng.uniform(size=m)
        u_b2 = rng.standard_normal(m)
        exp_b = rng.exponential(size=m)
        if m == 0:
            e = np.zeros(0)
            return UwbEpoch(e.astype(int), e.astype(int), e, e, e.astype(int))
        # vehicle-body blocking: another vehicle near the segment, strictly between the ends
        body = self._body_blocked(pos_ecef, i, j, tree)
        building = self.grid.blocked(plan_en[i], plan_en[j]) if self.grid is not None else np.zeros(m, bool)

        bias = np.where(body, p.body_bias_m[0] + (p.body_bias_m[1] - p.body_bias_m[0]) * u_bias, 0.0)
        bias = bias + np.where(body, np.abs(u_b2) * p.body_extra_sigma_m, 0.0)
        bias = np.where(building, p.building_bias_mean_m * exp_b, bias)
        rng_m = dist + bias + p.sigma_m * noise

        loss_p = np.where(self.bad[i, j], p.ge_loss_bad, p.ge_loss_good)
        fade = np.clip((dist - p.fade_start_m) / max(p.max_range_m - p.fade_start_m, 1e-6), 0.0, 1.0)
        loss_p = 1.0 - (1.0 - loss_p) * (1.0 - fade)
        loss_p = np.where(building, 1.0 - (1.0 - loss_p) * (1.0 - p.building_loss), loss_p)
        keep = (u_loss >= loss_p) & (dist <= p.max_range_m) & (rng_m > 0.0)
        kind = np.where(building, 2, np.where(body, 1, 0))
        return UwbEpoch(i[keep], j[keep], rng_m[keep], dist[keep], kind[keep])
