"""A factor kept as the call that builds it: what the window holds and a smoother process is sent.

GTSAM's Python wrapper pickles factors through boost's text archive, and at 256 vehicles that cost
the fusion server more than the second process saved (docs/performance-scale.md, "Cores inside
one server"). A `Recipe` is a builder of `coplane.fgo.factors` and its plain arguments (numbers,
numpy arrays, dataclasses), so it crosses a process boundary as those (`to_wire`; the builder is
pickled by name). Every builder is deterministic, so the process that solves a graph builds the
same factors, bit for bit, as any other would. Each process builds a recipe's factors once, when a
graph it solves first needs them, so a process never builds the factors of clusters it does not
solve.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Any

import gtsam


class Recipe:
    """`build(*args)`: one factor or a list of them (a vehicle epoch's pseudoranges).

    The window's links and ranges are recipes themselves (subclasses with their own fields), so a
    city's window holds no extra object per factor. Its arguments must not change once it is
    made: it may be built epochs later, or in another process, from what they hold then.
    """

    __slots__ = ("_factors", "args", "build")

    def __init__(self, build: Callable[..., Any], *args: Any) -> None:
        self.build = build
        self.args = args
        self._factors: tuple[gtsam.NonlinearFactor, ...] | None = None

    def factors(self) -> tuple[gtsam.NonlinearFactor, ...]:
        """The factors, built on the first call in this process."""
        if self._factors is None:
            made = self.build(*self.args)
            self._factors = tuple(made) if isinstance(made, list) else (made,)
        return self._factors

    def settle(self) -> None:
        """Build the factors now and drop the arguments: for a process that ships no recipe, so
        that it holds what it held before recipes, the factors alone."""
        self.factors()
        self.args = ()

    def factor(self) -> gtsam.NonlinearFactor:
        """The first factor: the one of a recipe that builds one."""
        return (self._factors or self.factors())[0]

    def __repr__(self) -> str:
        return f"{type(self).__name__}({getattr(self.build, '__name__', self.build)})"


def realise(recipes: Iterable[Recipe]) -> gtsam.NonlinearFactorGraph:
    """One graph of the recipes' factors, in order."""
    g = gtsam.NonlinearFactorGraph()
    for r in recipes:
        for f in r.factors():
            g.add(f)
    return g


Wire = list[tuple[Callable[..., Any], tuple[Any, ...]]]


def to_wire(recipes: Iterable[Recipe]) -> Wire:
    """The recipes as plain tuples for another process: builders (pickled by name) and arguments,
    never the factors built here."""
    return [(r.build, r.args) for r in recipes]


def from_wire(wire: Wire) -> gtsam.NonlinearFactorGraph:
    """The graph of recipes sent by `to_wire`, built in this process."""
    return realise(Recipe(build, *args) for build, args in wire)
