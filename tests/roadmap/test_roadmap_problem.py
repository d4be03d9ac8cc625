"""TilePlane.problem: what makes a stored or received tile unfit to give a plane, by name."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
from conftest import MakePass

from coplane.roadmap import PassSummary, RoadMapConfig, TileKey, TilePlane

CFG = RoadMapConfig()
KEY = TileKey(26_780, 43_000)


@pytest.fixture
def tile(make_pass: MakePass) -> TilePlane:
    """A sound tile: two lanes, a rejected pass, recent summaries with and without z."""
    t = TilePlane(KEY, 100.0)
    for k, lane in enumerate([-1.75, 1.75, -1.75, 1.75, 0.0, -1.75]):
        t.add_pass(make_pass(a=0.3, b=0.02, lane_n=lane, t=60.0 * k, vid=f"v{k % 2}"), CFG)
    t.add_pass(make_pass(a=5.0, lane_n=0.0, t=400.0), CFG)  # an outlier pass
    assert t.outlier_passes == 1 and t.cusum_pos + t.cusum_neg > 0.0 and len(t.recent) == 7
    return t


def _with_info(t: TilePlane, i: int, j: int, v: float) -> TilePlane:
    info = t.info.copy()
    info[i, j] = v
    return dataclasses.replace(t, info=info)


def _with_recent(t: TilePlane, **kw: Any) -> TilePlane:
    return dataclasses.replace(t, recent=[*t.recent[:-1], dataclasses.replace(t.recent[-1], **kw)])


DAMAGE: list[tuple[str, Callable[[TilePlane], TilePlane], str]] = [
    ("row beyond 85 deg", lambda t: dataclasses.replace(t, key=TileKey(10**9, 0)), "tile key outside the grid"),
    ("column beyond 180 deg", lambda t: dataclasses.replace(t, key=TileKey(KEY.row, 10**7)), "tile key outside the grid"),
    ("nan h0", lambda t: dataclasses.replace(t, h0_m=math.nan), "height out of range"),
    ("h0 at 20 km", lambda t: dataclasses.replace(t, h0_m=20_000.0), "height out of range"),
    ("h0 at -5 km", lambda t: dataclasses.replace(t, h0_m=-5_000.0), "height out of range"),
    ("2x2 info", lambda t: dataclasses.replace(t, info=np.eye(2)), "information of the wrong shape"),
    ("inf in info", lambda t: _with_info(t, 1, 1, math.inf), "non-finite information"),
    ("nan in eta", lambda t: dataclasses.replace(t, eta=np.array([math.nan, 0.0, 0.0])), "non-finite information"),
    ("non-symmetric info", lambda t: _with_info(t, 0, 1, t.info[0, 1] + 1e-9), "information matrix not symmetric"),
    ("negative offset info", lambda t: _with_info(t, 0, 0, -1.0), "information matrix not positive definite"),
    ("no info but passes", lambda t: dataclasses.replace(t, info=np.zeros((3, 3))), "information matrix not positive definite"),
    ("negative n_passes", lambda t: dataclasses.replace(t, n_passes=-1), "negative count"),
    ("negative version", lambda t: dataclasses.replace(t, version=-1), "negative count"),
    ("negative cusum run", lambda t: dataclasses.replace(t, cusum_neg_n=-2), "negative count"),
    ("nan time", lambda t: dataclasses.replace(t, updated_s=math.nan), "time not finite"),
    ("nan cusum", lambda t: dataclasses.replace(t, cusum_pos=math.nan), "change detector state invalid"),
    ("negative cusum", lambda t: dataclasses.replace(t, cusum_neg=-1.0), "change detector state invalid"),
    ("recent nan info", lambda t: _with_recent(t, info=np.full((3, 3), math.nan)), "invalid recent pass"),
    ("recent negative info", lambda t: _with_recent(t, info=-np.eye(3)), "invalid recent pass"),
    ("recent inf z", lambda t: _with_recent(t, z=math.inf), "invalid recent pass"),
    ("recent negative points", lambda t: _with_recent(t, n_points=-1), "invalid recent pass"),
]  # fmt: skip


def test_a_sound_tile_has_no_problem(tile: TilePlane) -> None:
    assert tile.problem(CFG) is None
    assert TilePlane(KEY, 100.0).problem(CFG) is None  # a new tile, no evidence yet
    assert math.isnan(tile.recent[0].z)  # the first pass's nan z is no problem
    assert dataclasses.replace(tile, h0_m=-400.0).problem(CFG) is None  # the Dead Sea


@pytest.mark.parametrize(("name", "damage", "reason"), DAMAGE, ids=[d[0] for d in DAMAGE])
def test_each_kind_of_damage_is_named(
    tile: TilePlane, name: str, damage: Callable[[TilePlane], TilePlane], reason: str
) -> None:
    assert damage(tile).problem(CFG) == reason, name


def test_problem_does_not_change_the_tile(tile: TilePlane) -> None:
    before = (tile.info.tobytes(), tile.eta.tobytes(), tile.version, len(tile.recent))
    tile.problem(CFG)
    assert (tile.info.tobytes(), tile.eta.tobytes(), tile.version, len(tile.recent)) == before
    assert all(isinstance(p, PassSummary) for p in tile.recent)
