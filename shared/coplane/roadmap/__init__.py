"""A persistent road-surface map that every pass of every vehicle refines (docs/roadmap.md).

- `grid`: a global grid of square tiles of `tile_size_m` (keys "r{row}c{col}");
- `tile.TilePlane`: one tile's road plane in information form, and the update rule for one pass
  (in-pass outlier removal, outlier passes, CUSUM change detection and re-learning, decay);
- `reference.CommonResidual`: the recent passes' median residual, what the whole fleet shares,
  which the change detection takes off so that it is not taken for a change of every tile;
- `builder.MapBuilder`: fused solutions -> trust filter, de-mapping -> passes;
- `roadmap.RoadMap`: the tiles in memory; `plane_at` gives a vehicle the plane under it;
- `geojson.tiles_geojson`: the tiles for viewers.

Persistence is `coplane.store.roadmap_db.RoadMapDb` (SQLite). Plane convention as in
`coplane.plane`: ``n . p + d = 0``, ``n`` unit and upward, ``d_antenna = d_road - h``.
"""

from coplane.roadmap.builder import MapBuilder, MapSample
from coplane.roadmap.config import RoadMapConfig
from coplane.roadmap.geojson import tile_feature, tiles_geojson
from coplane.roadmap.grid import (
    TileKey,
    tile_centre,
    tile_corners_lonlat,
    tile_frame,
    tile_of_ecef,
    tile_of_geodetic,
    tiles_around,
    tiles_in_bbox,
)
from coplane.roadmap.roadmap import MapPlane, RoadMap
from coplane.roadmap.tile import ChangeEvent, PassEvidence, PassSummary, TilePlane, TileUpdate

__all__ = [
    "ChangeEvent",
    "MapBuilder",
    "MapPlane",
    "MapSample",
    "PassEvidence",
    "PassSummary",
    "RoadMap",
    "RoadMapConfig",
    "TileKey",
    "TilePlane",
    "TileUpdate",
    "tile_centre",
    "tile_corners_lonlat",
    "tile_feature",
    "tile_frame",
    "tile_of_ecef",
    "tile_of_geodetic",
    "tiles_around",
    "tiles_geojson",
    "tiles_in_bbox",
]
