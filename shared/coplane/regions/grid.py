"""A vehicle's region and the region's shard.

Regions are cells of the road map's global metric grid (`coplane.roadmap.grid`, keys
"r{row}c{col}") at `RegionConfig.size_m`, not H3: the same reasons as for the map's tiles (exact
metric sizes, no compiled dependency, keys anyone can compute), and one grid for both means a
region is a whole number of map tiles when the sizes divide.
"""

from __future__ import annotations

import hashlib
from functools import lru_cache

import numpy as np
from numpy.typing import ArrayLike

from coplane.roadmap.grid import TileKey, tile_frame, tile_of_ecef, tiles_around

from .config import RegionConfig


def region_of_ecef(ecef: ArrayLike, cfg: RegionConfig, current: str | None = None) -> str:
    """The region of a position. With `current` (the vehicle's region so far), the vehicle stays
    in it until it is `hysteresis_m` inside another one, so a boundary drive does not flap."""
    p = np.asarray(ecef, dtype=float)
    new = str(tile_of_ecef(p, cfg.size_m))
    if current is None or new == current or cfg.hysteresis_m <= 0.0:
        return new
    near = {str(k) for k in tiles_around(p, cfg.hysteresis_m, cfg.size_m)}
    return current if current in near else new


@lru_cache(maxsize=1 << 16)  # a server asks for the same tiles at every commit
def region_of_tile(key: TileKey, tile_size_m: float, cfg: RegionConfig) -> str:
    """The region of a road-map tile: the one holding its centre (a tile is in one region when
    the region size is a multiple of the tile size). With several servers the owner of that region
    is the tile's one writer (docs/scale.md, "The road map across servers")."""
    return region_of_ecef(tile_frame(key, tile_size_m)[0], cfg)


@lru_cache(maxsize=1 << 16)  # asked for every vehicle a lockstep server may wait for, every message
def shard_of(region: str, shards: int) -> int:
    """A region's shard: a stable hash (BLAKE2b, not Python's salted `hash`) so that every process
    on every machine agrees."""
    digest = hashlib.blake2b(region.encode(), digest_size=8).digest()
    return int.from_bytes(digest, "big") % shards


def regions_near(ecef: ArrayLike, home: str, cfg: RegionConfig) -> list[str]:
    """The regions other than `home` with a point within `margin_m` of a position, sorted: where a
    vehicle's node message is copied, so every server sees the vehicles that can range with its
    own (a vehicle held in `home` by the hysteresis is inside the margin of the region it is in)."""
    if cfg.margin_m <= 0.0:
        return []
    near = {str(k) for k in tiles_around(np.asarray(ecef, dtype=float), cfg.margin_m, cfg.size_m)}
    return sorted(near - {home})
