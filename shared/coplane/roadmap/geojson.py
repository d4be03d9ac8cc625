"""The map's tiles as GeoJSON (RFC 7946): one polygon per tile, for viewers and `coplane map show`."""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Any

import numpy as np

from coplane.roadmap.config import RoadMapConfig
from coplane.roadmap.grid import tile_corners_lonlat
from coplane.roadmap.tile import TilePlane


def _num(x: float) -> float | None:
    """A JSON number, or None for NaN/inf (strict JSON has neither)."""
    x = float(x)
    return x if math.isfinite(x) else None


def tile_feature(tile: TilePlane, config: RoadMapConfig) -> dict[str, Any]:
    """One tile as a Feature; its plane's numbers are None while it has no offset information, or
    when its information gives no plane (a damaged tile: a viewer must not fail on it)."""
    height = sigma = grade_e = grade_n = slope_sigma = None
    if tile.info[0, 0] > 0.0:
        try:
            theta, cov = tile.estimate(config)
            h, s = tile.height_at(0.0, 0.0, config)
            slope_var = float(np.linalg.eigvalsh(cov[1:, 1:])[-1])
        except (ValueError, ArithmeticError, np.linalg.LinAlgError):
            pass
        else:
            height, sigma = _num(h), _num(s)
            grade_e, grade_n = _num(theta[1]), _num(theta[2])
            slope_sigma = _num(math.sqrt(max(slope_var, 0.0)))
    ring = [[lon, lat] for lon, lat in tile_corners_lonlat(tile.key, config.tile_size_m)]
    return {
        "type": "Feature",
        "id": str(tile.key),
        "geometry": {"type": "Polygon", "coordinates": [ring]},
        "properties": {
            "tile": str(tile.key),
            "height_m": height,
            "sigma_m": sigma,
            "grade_east": grade_e,
            "grade_north": grade_n,
            "slope_sigma": slope_sigma,
            "n_passes": int(tile.n_passes),
            "outlier_passes": int(tile.outlier_passes),
            "changes": int(tile.changes),
            "version": int(tile.version),
            "updated_s": _num(tile.updated_s),
            "usable": bool(tile.usable(config)),
        },
    }


def tiles_geojson(tiles: Iterable[TilePlane], config: RoadMapConfig) -> dict[str, Any]:
    """A FeatureCollection of the tiles, by key; plain JSON types only (json.dumps(allow_nan=False) works)."""
    ordered = sorted(tiles, key=lambda t: t.key)
    return {"type": "FeatureCollection", "features": [tile_feature(t, config) for t in ordered]}
