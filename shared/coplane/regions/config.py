"""The fleet-wide region settings: every agent and server of a fleet must use the same values."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class RegionConfig:
    """`size_m`: a region's edge. It must be well above the cooperation distances (UWB <= 500 m,
    planes <= 50 m) so that a cluster rarely spans more than two regions, and small enough that a
    city has many more regions than servers (load balance). `shards`: buckets of regions; a server
    subscribes to whole shards, so the number of key expressions it declares is bounded by this,
    not by the size of the city. `hysteresis_m`: a vehicle changes region only once it is this far
    inside the new one, so driving along a boundary does not flip it every epoch. `margin_m`: a
    vehicle this close to another region also sends its node message there, so the server of
    that region sees every vehicle that can range with its own (UWB reaches 500 m); with 4 km
    regions about a third of the vehicles are near a boundary at any time."""

    size_m: float = 4000.0
    shards: int = 64
    hysteresis_m: float = 50.0
    margin_m: float = 500.0

    def __post_init__(self) -> None:
        if not (self.size_m >= 100.0):
            raise ValueError(f"region size_m must be >= 100 m, got {self.size_m!r}")
        if not (1 <= self.shards <= 4096):
            raise ValueError(f"region shards must be in 1..4096, got {self.shards!r}")
        if not (0.0 <= self.margin_m < self.size_m / 2):
            raise ValueError(f"region margin_m must be in [0, size_m/2), got {self.margin_m!r}")
        if not (0.0 <= self.hysteresis_m < self.size_m / 4):
            raise ValueError(f"region hysteresis_m must be in [0, size_m/4), got {self.hysteresis_m!r}")
