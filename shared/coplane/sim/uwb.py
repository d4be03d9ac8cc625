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
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from coplane.sim.canyon import FootprintGrid
from coplane.typing import AnyArray


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

    def _candidate_pairs(self, pos: AnyArray) -> tuple[AnyArray, AnyArray, AnyArray]:
        n = self.n
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

    def step(self, pos_ecef: AnyArray, plan_en: AnyArray) -> UwbEpoch:
        """One epoch from antenna positions (N, 3) ECEF and their plan-view East-North (N, 2)."""
        p, rng = self.p, self.rng
        n = self.n
        # channel state evolves for every pair every epoch (fixed draw count: reproducible)
        u = rng.uniform(size=(n, n))
        self.bad = np.where(self.bad, u >= p.ge_bad_to_good, u < p.ge_good_to_bad)
        i, j, dist = self._candidate_pairs(pos_ecef)
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
        a, b = pos_ecef[i], pos_ecef[j]
        ab = b - a
        ll = np.maximum(np.einsum("pk,pk->p", ab, ab), 1e-9)
        body = np.zeros(m, dtype=bool)
        chunk = max(1, 2_000_000 // max(n, 1))
        for c0 in range(0, m, chunk):
            sl = slice(c0, c0 + chunk)
            rel = pos_ecef[None, :, :] - a[sl, None, :]
            tpar = np.einsum("pnk,pk->pn", rel, ab[sl]) / ll[sl, None]
            closest = a[sl, None, :] + tpar[..., None] * ab[sl, None, :]
            dd = np.linalg.norm(pos_ecef[None, :, :] - closest, axis=-1)
            inside = (tpar > 0.0) & (tpar < 1.0) & (dd < p.body_radius_m)
            inside[np.arange(inside.shape[0]), i[sl]] = False
            inside[np.arange(inside.shape[0]), j[sl]] = False
            body[sl] = inside.any(axis=1)
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
