"""The in-memory road-surface map: tiles by key, passes applied, planes served (docs/roadmap.md).

Pure: no I/O. `coplane.store.roadmap_db` persists it; a `RoadMap` is plain data (dicts, dataclasses,
numpy arrays), so it pickles to worker processes.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from coplane.geo import up_vector
from coplane.plane.fit import antenna_offset
from coplane.plane.history import project_to_road
from coplane.roadmap.config import RoadMapConfig
from coplane.roadmap.grid import TileKey, tile_frame, tile_of_ecef
from coplane.roadmap.reference import CommonResidual, ZReference
from coplane.roadmap.tile import ChangeEvent, PassEvidence, TilePlane, TileUpdate
from coplane.typing import Vec

# a pass, its outcome, the common residual it was tested against (None: not known yet, so not
# tested) and whether its tile was usable when it came (only those passes feed the common residual)
PassObserver = Callable[[PassEvidence, TileUpdate, ZReference | None, bool], None]


@dataclass(frozen=True, eq=False)
class MapPlane:
    """A tile's road plane at a vehicle, in the convention of `coplane.plane.fit`: unit upward
    `normal`, n . p + d_road = 0 on the road, d_antenna = d_road - antenna height. `sigma_m` is the
    road height's 1-sigma at the vehicle (with roughness: the factor's sigma), `offset_sigma_m` the
    plane's own height sigma at the tile centre, `tilt_sigma_rad` its least-determined slope.
    `centroid`: the tile centre on the antenna plane, the point a check of the plane refers to (as a
    fitted plane's centroid), so the plane can be checked when the vehicle has no SPP fix."""

    key: TileKey
    normal: Vec
    d_road: float
    d_antenna: float
    sigma_m: float
    offset_sigma_m: float
    tilt_sigma_rad: float
    n_passes: int
    version: int
    centroid: Vec


class RoadMap:
    """Tiles by key; `apply` adds passes, `plane_at` serves a vehicle the plane under it."""

    def __init__(
        self,
        config: RoadMapConfig | None = None,
        tiles: dict[TileKey, TilePlane] | None = None,
        mapped_until: dict[str, float] | None = None,
    ) -> None:
        self.config = config or RoadMapConfig()
        self.tiles: dict[TileKey, TilePlane] = dict(tiles) if tiles else {}
        # per vehicle, the time of the newest pass the map has taken: evidence at or before it is
        # the same evidence again (a recording replayed or built twice), see `is_mapped`
        self.mapped_until: dict[str, float] = dict(mapped_until) if mapped_until else {}
        self.dirty: set[TileKey] = set()
        self.rejected: Counter[str] = Counter()  # planes plane_at refused to give, by reason
        # the recent passes' residuals on usable tiles: what the fleet shares, which the change
        # detector must not take for a change (`coplane.roadmap.reference`); not persisted
        self.common = CommonResidual(self.config)
        # plane of each tile as of (tile object, version): see _plane
        self._planes: dict[TileKey, tuple[TilePlane, tuple[int, Vec, float, float, float]]] = {}

    def get(self, key: TileKey) -> TilePlane | None:
        return self.tiles.get(key)

    def is_mapped(self, vehicle_id: str, time_s: float) -> bool:
        """Whether the map already holds this vehicle's evidence from this instant: a vehicle's
        time only moves forward, so a sample at or before its newest mapped pass is one the map has
        seen (replaying a recording, or building a map from it twice, must not count it again)."""
        last = self.mapped_until.get(vehicle_id)
        return last is not None and time_s <= last

    def apply(self, passes: Iterable[PassEvidence], on_pass: PassObserver | None = None) -> list[ChangeEvent]:
        """Add passes in (time, vehicle, tile) order, creating tiles as needed (h0 from the first
        pass's mean height); returns the changes they caused. Touched tiles become dirty. Each
        pass is tested for a change against the fleet's common residual of the passes before it.
        `on_pass(pass, update, reference, usable)` sees every pass's test (what the change detector
        was given: bench/roadmap_change_evidence.py)."""
        ordered = sorted(passes, key=_order)
        changes: list[ChangeEvent] = []
        for p in ordered:
            key = p.key
            assert key is not None  # _order checked
            tile = self.tiles.get(key)
            if tile is None:
                if p.h_ref_m is None:
                    raise ValueError(f"pass of {p.vehicle_id} for new tile {key}: h_ref_m is needed for h0")
                u = np.asarray(p.points_enu, dtype=float)[:, 2]
                tile = self.tiles[key] = TilePlane(key, float(p.h_ref_m + float(u.mean())))
            usable = tile.usable(self.config)
            ref = self.common.reference(p.time_s)
            upd = tile.add_pass(p, self.config, ref)
            if usable:
                self.common.add(p.time_s, upd.residual_m)
            if on_pass is not None:
                on_pass(p, upd, ref, usable)
            self.dirty.add(key)
            self.mapped_until[p.vehicle_id] = max(self.mapped_until.get(p.vehicle_id, -math.inf), p.time_s)
            if upd.change is not None:
                changes.append(upd.change)
        return changes

    def take_dirty(self) -> list[TilePlane]:
        """Tiles changed since the last call, by key (what a database write needs), then clean."""
        out = [self.tiles[k] for k in sorted(self.dirty) if k in self.tiles]
        self.dirty = set()
        return out

    def drop(self, keys: Iterable[TileKey]) -> int:
        """Forget these tiles (an agent's map keeps only the tiles around it); how many were held."""
        n = 0
        for k in keys:
            n += self.tiles.pop(k, None) is not None
            self._planes.pop(k, None)
        return n

    def tile_at(self, ecef: ArrayLike) -> TilePlane | None:
        """The tile holding an ECEF position (a road point: project an antenna first)."""
        return self.tiles.get(tile_of_ecef(ecef, self.config.tile_size_m))

    def plane_at(self, antenna_ecef: ArrayLike, antenna_height_m: float) -> MapPlane | None:
        """The plane of the tile under an antenna, if the tile is usable and its height sigma at the
        vehicle is at most `max_use_sigma_m`; None otherwise. A tile whose numbers do not give a
        sound plane (singular or not positive definite information, a non-finite, non-unit or
        downward normal, a sigma that is not a positive number) gives None too, counted in `rejected`: it never reaches the graph."""
        cfg = self.config
        road = project_to_road(antenna_ecef, antenna_height_m)
        tile = self.tile_at(road)
        if tile is None or not tile.usable(cfg):
            return None
        try:
            version, normal, d_road, offset_sigma, tilt_sigma = self._plane(tile)
            sigma = tile.sigma_at_ecef(road, cfg)
        except _NotPositiveDefinite:
            self.rejected["information matrix not positive definite"] += 1
            return None
        except (ValueError, ArithmeticError, np.linalg.LinAlgError):  # e.g. singular information
            self.rejected["tile without a plane"] += 1
            return None
        if math.isfinite(sigma) and sigma > cfg.max_use_sigma_m:
            return None  # a sound tile, too uncertain here
        why = _plane_problem(normal, d_road, (sigma, offset_sigma, tilt_sigma), road)
        if why is not None:
            self.rejected[why] += 1
            return None
        d_antenna = antenna_offset(d_road, antenna_height_m)
        centre = tile_frame(tile.key, cfg.tile_size_m)[0]
        return MapPlane(
            key=tile.key,
            normal=normal,
            d_road=d_road,
            d_antenna=d_antenna,
            sigma_m=sigma,
            offset_sigma_m=offset_sigma,
            tilt_sigma_rad=tilt_sigma,
            n_passes=tile.n_passes,
            version=version,
            centroid=centre - (float(normal @ centre) + d_antenna) * normal,
        )

    def stats(self) -> dict[str, int]:
        """Counts for a summary line: tiles, usable tiles, accepted and rejected passes, changes."""
        tiles = self.tiles.values()
        return {
            "tiles": len(self.tiles),
            "usable_tiles": sum(t.usable(self.config) for t in tiles),
            "passes": sum(t.n_passes for t in tiles),
            "outlier_passes": sum(t.outlier_passes for t in tiles),
            "changes": sum(t.changes for t in tiles),
        }

    def _plane(self, tile: TilePlane) -> tuple[int, Vec, float, float, float]:
        """ECEF plane, offset sigma and tilt sigma of a tile, cached by version: a fleet asks for
        the same few tiles every epoch, and the ECEF conversion costs more than the solve."""
        hit = self._planes.get(tile.key)
        if hit is not None and hit[0] is tile and hit[1][0] == tile.version:
            return hit[1]
        normal, d_road = tile.plane_ecef(self.config)
        normal.flags.writeable = False
        _, cov = tile.estimate(self.config)
        if not np.isfinite(cov).all() or not float(np.linalg.eigvalsh(cov)[0]) > 0.0:
            # (info + prior)^-1 exists but is no covariance: every sigma from it would be a lie
            raise _NotPositiveDefinite(f"tile {tile.key}")
        slope_var = float(np.linalg.eigvalsh(cov[1:, 1:])[-1])
        out = (tile.version, normal, d_road, math.sqrt(float(cov[0, 0])), math.atan(math.sqrt(slope_var)))
        self._planes[tile.key] = (tile, out)
        return out


class _NotPositiveDefinite(ValueError):
    """A tile's information (with the slope prior) is not positive definite."""


def _plane_problem(normal: Vec, d_road: float, sigmas: tuple[float, ...], road: ArrayLike) -> str | None:
    """Why a tile's plane must not reach the graph, or None."""
    if not (np.isfinite(normal).all() and math.isfinite(d_road)):
        return "non-finite plane"
    if abs(float(np.linalg.norm(normal)) - 1.0) > 1e-6:
        return "normal not a unit vector"
    if float(normal @ up_vector(np.asarray(road, dtype=float))) <= 0.5:
        return "normal not upward"
    if not all(math.isfinite(x) and x > 0.0 for x in sigmas):
        return "sigma not a positive number"
    return None


def _order(p: PassEvidence) -> tuple[float, str, TileKey]:
    if p.key is None:
        raise ValueError(f"pass of {p.vehicle_id} at {p.time_s}: no tile key")
    return (p.time_s, p.vehicle_id, p.key)
