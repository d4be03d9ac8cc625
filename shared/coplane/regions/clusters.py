"""Which server solves a cluster of vehicles that spans regions (docs/scale.md, "Boundaries").

The estimator solves vehicles linked by ranges within its window as one cluster. When such a
cluster spans two regions owned by different servers, exactly one of them must solve it, or each
would solve half of it with the ranges across the boundary lost. The rule: a cluster belongs to
the owner of the shard of its *anchor*, the member with the smallest vehicle id, in the anchor's
own region. A vehicle within `margin_m` (the UWB range) of other regions also sends its node
message to them (`regions_near`), so both sides of a boundary see the vehicles that can range
across it, build the same cluster and agree on its owner. A chain of ranged vehicles reaching
further than the margin into the other region can still be seen differently by the two servers.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping

from coplane.components import UnionFind
from coplane.gtime import GpsTime


class RangeGraph:
    """Pairs of vehicles ranged within the last `window_s` seconds: the links the estimator's
    window still holds, so clusters here match the estimator's (`Window.partition`)."""

    def __init__(self, window_s: float) -> None:
        self.window_s = float(window_s)
        self.last: dict[tuple[str, str], GpsTime] = {}

    def add(self, t: GpsTime, pairs: Iterable[tuple[str, str]]) -> None:
        """Record the pairs ranged at epoch `t` and forget those older than the window."""
        for a, b in pairs:
            if a != b:
                self.last[(a, b) if a < b else (b, a)] = t
        old = [p for p, tp in self.last.items() if t - tp > self.window_s]
        for p in old:
            del self.last[p]

    def clusters(self, vehicles: Iterable[str]) -> list[list[str]]:
        """Connected components of `vehicles` under the recorded pairs, each sorted, sorted by
        their first member (the anchor)."""
        uf = UnionFind(vehicles)
        for a, b in self.last:
            if a in uf.parent and b in uf.parent:
                uf.union(a, b)
        return uf.groups()


def cluster_owner(
    members: Iterable[str], region: Mapping[str, str], owner_of_region: Callable[[str], str | None]
) -> str | None:
    """The server that solves a cluster: the owner of its anchor's region (None: unknown region)."""
    anchor = min(members)
    r = region.get(anchor)
    return None if r is None else owner_of_region(r)
