"""With regions a server's key is its own, and what it says of vehicles is held to its regions:
a consumer's `GateSet` drops the states of vehicles no region of that server reaches
(`regions.may_speak_of`, docs/scale.md "Who may speak of a vehicle")."""

from __future__ import annotations

from pathlib import Path

from support.api import FLEET, T0, ecef_at, solution, vehicle_state

from coplane.bus.gates import GateSet
from coplane.messages import SolutionMessage
from coplane.regions import (
    MOVE_GRACE_S,
    RegionConfig,
    assignment,
    may_speak_of,
    owned_shards,
    region_of_ecef,
    shard_of,
)

CFG = RegionConfig(size_m=1100.0, margin_m=500.0)
LIVE = ["s1", "s2"]
FLEET_DIR = Path("fleet-recording")
OWNERS = assignment(LIVE, CFG.shards)


def _shards(server: str) -> set[int]:
    return owned_shards(server, LIVE, CFG.shards)


def _deep_in(server: str) -> tuple[float, float, float]:
    """A place that only `server` may speak of: every region within the reach is its own."""
    for e in range(0, 40_000, 300):
        p = ecef_at(float(e), 0.0)
        other = next(s for s in LIVE if s != server)
        if may_speak_of(p, _shards(server), CFG) and not may_speak_of(p, _shards(other), CFG):
            return p
    raise AssertionError(f"no place of {server} alone")


class _Clock:
    def __init__(self) -> None:
        self.t = 1000.0

    def __call__(self) -> float:
        return self.t


def _gates(clock: _Clock, **kw: object) -> GateSet:
    gs = GateSet(FLEET, regions=CFG, clock=clock, **kw)  # type: ignore[arg-type]
    for s in LIVE:
        gs.server_token(s, True)
    return gs


def _sol(k: int, *states: tuple[str, tuple[float, float, float]]) -> SolutionMessage:
    s = solution(k, T0 + float(k), [vehicle_state(v, p) for v, p in states])
    return s.model_copy(update={"generation": "00c0ffee00c0ffee"})


def test_a_server_speaks_only_of_vehicles_its_regions_reach() -> None:
    clock = _Clock()
    gs = _gates(clock)
    mine, theirs = _deep_in("s2"), _deep_in("s1")
    clock.t += MOVE_GRACE_S + 1.0
    v = gs.check("s2", _sol(0, ("a", mine), ("b", theirs)), 0.0)
    assert v.accepted and [s.vehicle_id for s in v.solution.vehicles] == ["a"]  # type: ignore[union-attr]
    assert v.dropped == (("b", "vehicle-not-owner"),)
    assert gs.counts["vehicle-not-owner"] == 1
    # the owner of that place may: the same state on s1's key is kept
    assert [s.vehicle_id for s in gs.check("s1", _sol(0, ("b", theirs)), 0.0).solution.vehicles] == ["b"]  # type: ignore[union-attr]


def test_near_a_boundary_both_servers_may_speak() -> None:
    """A vehicle held in its region by the hysteresis, or fused a little off its fix, is within
    the reach of its own server's regions: the boundary is never a reason to drop it."""
    a, b = _deep_in("s1"), _deep_in("s2")
    # walk from a place of s1 alone to one of s2 alone: every point on the way is someone's
    for i in range(101):
        p = tuple(x + (y - x) * i / 100 for x, y in zip(a, b, strict=True))
        home = OWNERS[shard_of(region_of_ecef(p, CFG), CFG.shards)]
        assert may_speak_of(p, _shards(home), CFG)  # its region's owner always may


def test_no_check_within_the_grace_after_a_change_nor_for_the_single_server() -> None:
    clock = _Clock()
    gs = _gates(clock)
    theirs = _deep_in("s1")
    assert len(gs.check("s2", _sol(0, ("b", theirs)), 0.0).solution.vehicles) == 1  # type: ignore[union-attr]
    clock.t += MOVE_GRACE_S + 1.0
    assert len(gs.check("", _sol(0, ("b", theirs)), 0.0).solution.vehicles) == 1  # type: ignore[union-attr]
    gs.server_token("s3", True)  # a change: views of who owns what may differ for a while
    assert len(gs.check("s2", _sol(1, ("b", theirs)), 0.0).solution.vehicles) == 1  # type: ignore[union-attr]
    gs.server_token("s3", True)  # the same token again is no change
    clock.t += MOVE_GRACE_S + 1.0
    owners = assignment([*LIVE, "s3"], CFG.shards)
    shards2 = {k for k, o in owners.items() if o == "s2"}
    kept = gs.check("s2", _sol(2, ("b", theirs)), 0.0).solution.vehicles  # type: ignore[union-attr]
    assert len(kept) == int(may_speak_of(theirs, shards2, CFG))


def test_a_server_whose_token_is_down_speaks_of_nobody_and_exempt_vehicles_pass() -> None:
    clock = _Clock()
    gs = _gates(clock, exempt=["a"])
    mine = _deep_in("s2")
    clock.t += MOVE_GRACE_S + 1.0
    v = gs.check("s9", _sol(0, ("a", mine), ("b", mine)), 0.0)  # s9 has no token: owns nothing
    assert [s.vehicle_id for s in v.solution.vehicles] == ["a"]  # type: ignore[union-attr]
    gs.server_token("s2", False)
    clock.t += MOVE_GRACE_S + 1.0
    assert [s.vehicle_id for s in gs.check("s2", _sol(1, ("b", mine)), 0.0).solution.vehicles] == []  # type: ignore[union-attr]
    assert gs.counts["vehicle-not-owner"] == 2


def test_every_consumer_of_a_fleet_with_regions_holds_servers_to_them() -> None:
    """The API takes the same region flags as the servers (`coplane fleet --servers N` passes
    `--regions` to it), and its gate then applies the rule; without them it does not."""
    from coplane.api.app import create_app
    from coplane.api.bus_client import LocalBus
    from coplane.api.settings import ApiSettings
    from coplane.fleet.launcher import api_spec

    app = create_app(ApiSettings(fleet=FLEET, regions=True, region_size_m=1100.0), LocalBus())
    assert app.state.fleet.gate.regions == RegionConfig(size_m=1100.0)
    assert create_app(ApiSettings(fleet=FLEET), LocalBus()).state.fleet.gate.regions is None
    assert "--regions" in api_spec(FLEET_DIR, "tcp/127.0.0.1:7447", servers=2).args
    assert "--regions" not in api_spec(FLEET_DIR, "tcp/127.0.0.1:7447", servers=1).args


def test_a_held_new_run_s_first_solution_is_held_to_the_regions_when_released() -> None:
    clock = _Clock()
    gs = _gates(clock)
    mine, theirs = _deep_in("s2"), _deep_in("s1")
    clock.t += MOVE_GRACE_S + 1.0
    assert gs.check("s2", _sol(0, ("a", mine)), 0.0).accepted
    new_run = _sol(1, ("a", mine), ("b", theirs)).model_copy(update={"generation": "0123456789abcdef"})
    assert gs.check("s2", new_run, 0.5).reason == "new-generation"  # s2's token is still up: held
    gs.gates["s2"].server_gone()  # its run is over (as when its token goes, without a change here)
    released = gs.release(0.6)
    assert released is not None and [s.vehicle_id for s in released.vehicles] == ["a"]
