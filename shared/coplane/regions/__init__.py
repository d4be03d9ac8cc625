"""Regions: how a city fleet is spread over fusion servers without a coordinator (docs/scale.md).

- `grid`: a vehicle's region (a square cell of the road map's global grid, `region_size_m` wide)
  and its shard (a stable hash of the region into `shards` buckets: the unit servers subscribe to);
- `ownership`: which live server owns a shard (rendezvous hashing: every server computes the
  same answer from the same list of live servers);
- `clusters`: which server solves a cluster of vehicles linked by ranges across a region boundary
  (vehicles near a boundary also send to the regions within `margin_m`: `regions_near`).
"""

from coplane.regions.clusters import RangeGraph
from coplane.regions.config import RegionConfig
from coplane.regions.grid import region_of_ecef, region_of_tile, regions_near, shard_of
from coplane.regions.ownership import MOVE_GRACE_S, assignment, may_speak_of, owned_shards, owner

__all__ = [
    "MOVE_GRACE_S",
    "RangeGraph",
    "RegionConfig",
    "assignment",
    "may_speak_of",
    "owned_shards",
    "owner",
    "region_of_ecef",
    "region_of_tile",
    "regions_near",
    "shard_of",
]
