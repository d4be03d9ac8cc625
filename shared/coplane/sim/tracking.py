"""Signal strength and tracking: which satellites each receiver reports, and with what C/N0.

C/N0 falls towards the horizon, differs per receiver and satellite, wanders slowly and drops
further for reflected (NLOS) signals; a satellite is reported once it has stayed above the
elevation mask and the tracking threshold for the re-acquisition time, which is what makes a
receiver leaving an underpass come back gradually. Parameters: coplane.sim.errors.Cn0Params and
TrackingParams; see docs/simulator.md.
"""

from __future__ import annotations

import math

import numpy as np

from coplane.gnss.constants import is_bds_geo
from coplane.sim.canyon import BLOCKED, NLOS
from coplane.sim.errors import GaussMarkov, component_rng
from coplane.sim.world import World
from coplane.typing import AnyArray

MAX_CN0_DBHZ = 60.0


class Tracking:
    """C/N0 model and per-satellite lock counters of every receiver (the "cn0" random stream)."""

    def __init__(self, world: World, seed: int, nlos_cn0_loss_db: AnyArray) -> None:
        rx_params = world.rx_params
        n_rx, n_sat = world.n_rx, len(world.sats)
        geo_sat = np.array([is_bds_geo(s) for s in world.sats])
        cn0_rng = component_rng(seed, "cn0")
        self.zenith = np.array([p.cn0.zenith_dbhz for p in rx_params]) + np.array(
            [p.zenith_spread_db for p in rx_params]
        ) * cn0_rng.standard_normal(n_rx)
        self.drop = np.array([p.cn0.horizon_drop_db for p in rx_params])[:, None]
        sat_off = np.array([p.cn0.sat_sigma_db for p in rx_params])[:, None] * cn0_rng.standard_normal(
            (n_rx, n_sat)
        )
        sat_off += np.array([p.cn0.bds_geo_offset_db for p in rx_params])[:, None] * geo_sat[None, :]
        self.sat_offset = sat_off
        self.gm = GaussMarkov(
            (n_rx, n_sat), world.scenario.vehicle_receiver.cn0.noise_tau_s, world.dt, cn0_rng
        )
        self.noise = np.array([p.cn0.noise_sigma_db for p in rx_params])[:, None]
        self.threshold = np.array([p.cn0.track_threshold_dbhz for p in rx_params])[:, None]
        self.nlos_loss = nlos_cn0_loss_db
        self.mask = np.array([math.radians(p.tracking.elevation_mask_deg) for p in rx_params])[:, None]
        self.reacquire = np.array([p.tracking.reacquire_epochs for p in rx_params])[:, None]
        self.lock = np.broadcast_to(self.reacquire - 1, (n_rx, n_sat)).copy()

    def above_mask(self, avail: AnyArray, el: AnyArray) -> AnyArray:
        """(N, S) satellites with an ephemeris above each receiver's elevation mask."""
        return avail[None, :] & (el > self.mask)

    def step(self, el: AnyArray, above: AnyArray, state: AnyArray) -> tuple[AnyArray, AnyArray]:
        """Advance one epoch: (C/N0 in dB-Hz, reported mask), both (N, S)."""
        cn0 = self.zenith[:, None] - self.drop * (1.0 - np.sin(np.maximum(el, 0.0))) ** 2 + self.sat_offset
        cn0 = cn0 + self.noise * self.gm.step()
        cn0 = np.where(state == NLOS, cn0 - self.nlos_loss, cn0)
        cn0 = np.clip(cn0, 0.0, MAX_CN0_DBHZ)
        trackable = above & (state != BLOCKED) & (cn0 >= self.threshold)
        self.lock = np.where(trackable, self.lock + 1, 0)
        reported = trackable & (self.lock >= self.reacquire)
        return cn0, reported
