"""Disjoint sets (union-find) for grouping vehicles linked by ranges: the estimator's clusters
(`fgo.window`), the range bounds (`steps.fusion.bounded_ranges`), the servers' cluster rule
(`regions.clusters`) and the DD baseline's spanning forest all need the same small structure.

The root of a set is always its smallest member, so components come out the same whatever order
the links arrive in (every process that groups the same links gets the same clusters).
"""

from __future__ import annotations

from collections.abc import Iterable


class UnionFind:
    """Disjoint sets of string ids with path halving; roots are the smallest member."""

    def __init__(self, items: Iterable[str] = ()) -> None:
        self.parent: dict[str, str] = {}
        self.size: dict[str, int] = {}
        for v in items:
            self.add(v)

    def add(self, v: str) -> None:
        if v not in self.parent:
            self.parent[v] = v
            self.size[v] = 1

    def find(self, v: str) -> str:
        parent = self.parent
        while parent[v] != v:
            parent[v] = parent[parent[v]]
            v = parent[v]
        return v

    def union(self, a: str, b: str) -> bool:
        """Join the sets of `a` and `b`; False if they were one already."""
        ra, rb = self.find(a), self.find(b)
        if ra == rb:
            return False
        if rb < ra:
            ra, rb = rb, ra
        self.parent[rb] = ra
        self.size[ra] += self.size.pop(rb)
        return True

    def union_within(self, a: str, b: str, cap: int) -> bool:
        """Join the sets of `a` and `b` unless the joined set would have more than `cap` members
        (0: no bound); whether they are one set now. The rule of both range bounds (one epoch's,
        `steps.fusion.bounded_ranges`, and the estimator window's, `fgo.window.Window.bounded`)."""
        if self.find(a) != self.find(b) and cap > 0 and self.set_size(a) + self.set_size(b) > cap:
            return False
        self.union(a, b)
        return True

    def set_size(self, v: str) -> int:
        return self.size[self.find(v)]

    def groups(self) -> list[list[str]]:
        """Every set, each sorted, sorted by its first (smallest) member."""
        out: dict[str, list[str]] = {}
        for v in self.parent:
            out.setdefault(self.find(v), []).append(v)
        return sorted((sorted(g) for g in out.values()), key=lambda g: g[0])
