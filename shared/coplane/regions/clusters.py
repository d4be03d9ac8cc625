"""The clusters of vehicles linked by ranges, as a fusion server sees them at region boundaries
(docs/scale.md, "Boundaries").

The estimator solves vehicles linked by ranges within its window as one cluster. A vehicle within
`margin_m` (the UWB range) of other regions also sends its node message to them (`regions_near`),
so the servers on both sides of a boundary see the vehicles that can range across it. Each server
solves every cluster that holds a vehicle of its own regions, whole, and answers only for its own
vehicles (`coplane.fusion_server.regions.RegionRole.select`): a vehicle is answered exactly once,
by its own region's server, with no agreement needed on who owns a cluster. A chain of ranged
vehicles reaching further than the margin into another region is seen in part only, and solved
without the far part there.
"""

from __future__ import annotations

from collections.abc import Iterable

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
