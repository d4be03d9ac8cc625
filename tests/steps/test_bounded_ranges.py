"""`bounded_ranges` (issue 16): a dense city's range graph is cut into small clusters of nearest
peers, deterministically, and a small fleet keeps every range."""

from __future__ import annotations

import itertools

import numpy as np

from coplane.estimation.contract import RangeObs
from coplane.steps.fusion import bounded_ranges


def _ranges(n: int, seed: int = 1) -> dict[tuple[str, str], RangeObs]:
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0.0, 800.0, (n, 2))
    ids = [f"v{i:03d}" for i in range(n)]
    out = {}
    for i, j in itertools.combinations(range(n), 2):
        d = float(np.linalg.norm(xy[i] - xy[j]))
        if d <= 500.0:
            out[(ids[i], ids[j])] = RangeObs(ids[i], ids[j], d, 0.3)
    return out


def _clusters(pairs: dict[tuple[str, str], RangeObs]) -> list[set[str]]:
    groups: list[set[str]] = []
    for a, b in pairs:
        hit = [g for g in groups if a in g or b in g]
        merged = set().union({a, b}, *hit)
        groups = [g for g in groups if g not in hit] + [merged]
    return groups


def test_a_small_fleet_keeps_every_range() -> None:
    r = _ranges(4)
    assert bounded_ranges(r, 8, 16) is r


def test_a_dense_fleet_is_cut_into_bounded_clusters_of_nearest_peers() -> None:
    r = _ranges(200)
    kept = bounded_ranges(r, 8, 16)
    assert set(kept) < set(r)
    degree: dict[str, int] = {}
    for a, b in kept:
        degree[a] = degree.get(a, 0) + 1
        degree[b] = degree.get(b, 0) + 1
    assert max(degree.values()) <= 8
    assert max(len(c) for c in _clusters(kept)) <= 16
    # the shortest range of the fleet is always kept; the order of the input does not matter
    shortest = min(r, key=lambda p: r[p].range_m)
    assert shortest in kept
    assert bounded_ranges(dict(reversed(list(r.items()))), 8, 16) == kept
    # idempotent: a server that solves a subset of already bounded clusters keeps them whole
    assert bounded_ranges(kept, 8, 16) == kept
