"""The `city` scenario (load generation): several loops of a street grid, platoons that meet and
part, a recording in the usual format, deterministic from the seed, and the k-d tree UWB path."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest

import coplane.sim.uwb as uwb_mod
from coplane.recording.manifest import load_manifest
from coplane.recording.reader import open_recording
from coplane.sim.city import CityParams, city_side_m
from coplane.sim.city_world import City, _decode, build_city
from coplane.sim.errors import component_rng
from coplane.sim.generate import run_simulation
from coplane.sim.result import SimResult
from coplane.sim.scenarios import get_scenario
from coplane.sim.write import write_recording

N, SECONDS, SEED = 20, 30.0, 2


@pytest.fixture(scope="module")
def city() -> City:
    return build_city(get_scenario("city"), N, round(SECONDS), SEED)


@pytest.fixture(scope="module")
def result() -> SimResult:
    return run_simulation("city", N, SECONDS, seed=SEED)


def _platoon_of(city: City) -> np.ndarray:
    out = np.full(N, -1)
    for k, q in enumerate(city.platoons):
        out[q.first : q.first + q.size] = k
    return out


def _digest(root: Path) -> dict[str, str]:
    return {
        p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(root.rglob("*"))
        if p.is_file()
    }


def test_vehicles_drive_in_platoons_on_several_loops(city: City) -> None:
    plat = _platoon_of(city)
    assert (plat >= 0).all()
    sizes = [q.size for q in city.platoons]
    assert (
        sum(sizes) == N and all(1 <= k <= 6 for k in sizes) and sum(k >= 2 for k in sizes) >= len(sizes) - 1
    )
    loops, _ = _decode(city.track.s, city.road.lengths)
    assert len(np.unique(loops)) >= 3
    assert (loops == loops[0]).all()  # a vehicle keeps to its loop
    for q in city.platoons:  # platoon members share a loop and stay together (cohesion)
        members = slice(q.first, q.first + q.size)
        assert (loops[0, members] == q.loop).all()
        spread = np.linalg.norm(
            city.track.enu[:, members, None, :2] - city.track.enu[:, None, members, :2], axis=-1
        )
        assert spread.max() < 250.0
    speed = city.track.speed
    assert speed.min() >= 5.0 - 1e-9 and speed.max() <= 15.0 + 1e-9


def test_platoons_meet_and_part(city: City) -> None:
    """Pairs from different platoons come within UWB range, get close, and later part again."""
    e = city.track.ecef
    d = np.linalg.norm(e[:, :, None] - e[:, None, :], axis=-1)
    plat = _platoon_of(city)
    other = plat[:, None] != plat[None, :]
    near = d <= get_scenario("city").uwb.max_range_m  # type: ignore[union-attr]
    first_in = np.where(near.any(axis=0), near.argmax(axis=0), 10**6)
    last_in = np.where(near.any(axis=0), len(e) - 1 - near[::-1].argmax(axis=0), -1)
    meet = other & ~near[0] & near.any(axis=0)  # out of range at the start, in range later
    part = other & (last_in < len(e) - 1) & (first_in <= last_in)  # in range, then out
    assert meet.sum() > 0 and part.sum() > 0
    assert (other & (d.min(axis=0) < 100.0)).sum() > 0


def test_uwb_ranges_cross_platoons_and_respect_the_range_limit(result: SimResult, city: City) -> None:
    plat = _platoon_of(city)
    index = {vid: i for i, vid in enumerate(result.vehicle_ids)}
    pairs = {(index[u.a], index[u.b]) for u in result.uwb}
    assert any(plat[a] != plat[b] for a, b in pairs)
    assert max(u.range_m for u in result.uwb) < 500.0 + 3.0  # noise and NLOS bias on top of 500 m


def test_shared_streets_agree_between_loops(city: City) -> None:
    """Terrain and buildings belong to the city: every loop's facades sit on a building footprint,
    and the ground is one smooth surface (zero at the origin, grades at most 5 %)."""
    grid = city.canyon.footprint_grid()
    hits, total = 0, 0
    for loop_canyon in city.canyon.loops:
        for side, row in loop_canyon.rows.items():
            mid = (row.s0 + row.s1) / 2.0
            behind = loop_canyon.road.plan_point(mid, side * (row.setback + 1.0))
            total += len(mid)
            ij = np.floor((behind - grid.origin) / grid.cell_m).astype(int)
            hits += int(grid.occupied[ij[:, 0], ij[:, 1]].sum())
    assert total > 50 and hits / total > 0.97
    assert abs(float(city.layout.terrain.z(np.zeros(2)))) < 1e-9
    for road in city.road.loops:
        s = np.arange(0.0, road.length_m, 1.0)
        assert np.abs(road.profile.grade(s)).max() <= 0.05
        assert np.allclose(np.diff(road.profile.z(s)), road.profile.grade(s[:-1] + 0.5), atol=1e-4)


def test_city_grows_with_the_fleet() -> None:
    p = CityParams()
    assert city_side_m(p, 1000) == 3000.0
    assert city_side_m(p, 4000) == 6000.0 and city_side_m(p, 20) == 1000.0
    big = build_city(get_scenario("city"), 200, 2, 0)
    assert len(big.road.loops) == 8 and big.layout.side_m == pytest.approx(3000.0 * np.sqrt(0.2))


def test_recording_loads_and_is_deterministic(result: SimResult, tmp_path: Path) -> None:
    a = write_recording(result, tmp_path / "a")
    man = load_manifest(a)
    assert len(man.vehicles) == N and man.base is not None and man.uwb is not None
    rec = open_recording(a)
    assert rec.problems.total == 0, rec.problems.items[:5]
    assert len(rec.base_epochs()) == SECONDS and len(rec.vehicle_epochs("u7")) == SECONDS
    assert len(rec.uwb()) == len(result.uwb) > 0
    b = write_recording(run_simulation("city", N, SECONDS, seed=SEED), tmp_path / "b")
    assert _digest(a) == _digest(b)
    c = build_city(get_scenario("city"), N, 2, SEED + 1)
    assert not np.allclose(c.track.enu[0], result.track.enu[0])


def test_kd_tree_uwb_matches_all_pairs(city: City, monkeypatch: pytest.MonkeyPatch) -> None:
    """Big fleets use a k-d tree for neighbours and blocking; it must give the all-pairs answer."""
    sc = get_scenario("city")
    assert sc.uwb is not None
    grid = city.canyon.footprint_grid()
    out = []
    for limit in (10**6, 3):
        monkeypatch.setattr(uwb_mod, "DENSE_MAX_VEHICLES", limit)
        sim = uwb_mod.UwbSimulator(N, sc.uwb, grid, component_rng(SEED, "uwb"))
        out.append([sim.step(city.track.ecef[k], city.track.enu[k][:, :2]) for k in range(0, 30, 3)])
    for a, b in zip(*out, strict=True):
        for f in ("i", "j", "range_m", "true_m", "nlos"):
            assert np.array_equal(getattr(a, f), getattr(b, f)), f
