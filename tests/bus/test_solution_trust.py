"""The consumers' `SolutionGate` (issue 13): what the API, the agents and the collector take from the
`solution` key. Hand-made solutions, a fake wall clock, no bus."""

from __future__ import annotations

from pathlib import Path
from threading import Lock

import pytest
from support.api import FLEET, T0, ecef_at, solution, vehicle_state

from coplane.bus import encode
from coplane.bus.gates import GateSet
from coplane.bus.trust import SolutionGate, on_earth
from coplane.evaluate.runner import MethodRun
from coplane.fleet.collector import Collector
from coplane.gtime import GpsTime
from coplane.messages import SolutionMessage
from coplane.store import SolutionLog

GEN = "00c0ffee00c0ffee"
WEEK_S = 7 * 86_400.0


def sol(
    k: float, *pos: tuple[str, tuple[float, float, float]], gen: str | None = GEN, **kw: object
) -> SolutionMessage:
    """The solution of epoch T0 + k, stamped with a generation."""
    states = [vehicle_state(v, p) for v, p in pos] or [vehicle_state("a", ecef_at(0, 0))]
    s = solution(int(k), T0 + float(k), states, **kw)  # type: ignore[arg-type]
    return s.model_copy(update={"generation": gen})


def test_on_earth_band() -> None:
    assert on_earth(ecef_at(0, 0)) and on_earth(ecef_at(0, 0, 3000.0))
    assert not on_earth((0.0, 0.0, 0.0))  # was served as latitude 90 degrees
    assert not on_earth(ecef_at(0, 0, 50_000.0)) and not on_earth(ecef_at(0, 0, -5_000.0))
    assert not on_earth((1e7, 0.0, 0.0))


def test_forward_only_repeat_stale_and_far_ahead() -> None:
    g = SolutionGate(FLEET)
    for k in range(5):
        assert g.check(sol(k), 100.0 + k).accepted
    assert g.check(sol(4), 104.5).reason == "repeat"  # a resend / the republish after a resume
    assert g.check(sol(2), 104.6).reason == "stale"
    week_ago = sol(0).model_copy(update={"epoch": sol(0).epoch.model_copy(update={"week": T0.week - 1})})
    assert g.check(week_ago, 104.7).reason == "stale"  # a week earlier: no reset
    week_ahead = week_ago.model_copy(update={"epoch": sol(0).epoch.model_copy(update={"week": T0.week + 1})})
    assert g.check(week_ahead, 104.8).reason == "too-far-ahead"
    assert g.check(sol(5), 105.0).accepted and g.generation == GEN and g.resets == 0
    # a fleet that pauses: epochs do not move; a recording gap of 20 min after 10 wall seconds is fine
    assert g.check(sol(5 + 1200), 115.0).accepted
    assert g.counts == {"repeat": 1, "stale": 2, "too-far-ahead": 1}


def test_fleet_method_and_off_earth_reject_the_whole_message() -> None:
    g = SolutionGate(FLEET, method="pc")
    assert g.check(sol(0, fleet="other"), 0.0).reason == "wrong-fleet"
    assert g.check(sol(0, method="mci"), 0.0).reason == "wrong-method"
    bad = sol(0, ("a", ecef_at(0, 0)), ("b", (0.0, 0.0, 0.0)))
    assert g.check(bad, 0.0).reason == "off-earth"
    assert g.run is None  # nothing taken from a rejected message


def test_vehicle_jump_unknown_and_cap_drop_only_that_vehicle() -> None:
    g = SolutionGate(FLEET, vehicles=["a", "b"])
    assert g.check(sol(0, ("a", ecef_at(0, 0)), ("b", ecef_at(50, 0))), 0.0).accepted
    v = g.check(sol(1, ("a", ecef_at(5000, 0)), ("b", ecef_at(60, 0)), ("zz", ecef_at(0, 0))), 1.0)
    assert v.solution is not None and [s.vehicle_id for s in v.solution.vehicles] == ["b"]
    assert v.dropped == (("a", "vehicle-jump"), ("zz", "vehicle-unknown"))
    # the 5 km forgery did not move the reference: a is judged against its last accepted position
    assert g.check(sol(2, ("a", ecef_at(300, 0))), 2.0).accepted  # 200 m/s * 2 s + 500 m allows it
    # nothing left of a message: rejected without moving the epoch, the genuine one still counts
    assert g.check(sol(3, ("a", ecef_at(300 + 800, 0))), 3.0).reason == "no-trusted-vehicle"
    assert g.check(sol(3, ("a", ecef_at(310, 0))), 3.1).accepted and g.counts["vehicle-jump"] == 2
    # after a long absence the bound grows with the epoch gap
    assert g.check(sol(60, ("a", ecef_at(5000, 0))), 60.0).dropped == ()
    capped = SolutionGate(FLEET, max_vehicles=2)
    v = capped.check(sol(0, *((f"v{i}", ecef_at(10.0 * i, 0)) for i in range(4))), 0.0)
    assert v.dropped == (("v2", "too-many-vehicles"), ("v3", "too-many-vehicles"))


def test_a_message_that_continues_no_tracked_vehicle_never_takes_the_epoch() -> None:
    """Found by the live hostile run (docs/reliability/hostile-input.md): an empty forgery, or one
    whose tracked vehicles all jumped beside a never-seen one, used to become the newest epoch, so
    the genuine solution of that epoch was a "repeat" and lockstep agents stalled."""
    g = SolutionGate(FLEET, vehicles=["a", "b", "u4"])
    assert g.check(sol(0, ("a", ecef_at(0, 0)), ("b", ecef_at(50, 0))), 0.0).accepted
    empty = sol(1).model_copy(update={"vehicles": []})
    assert g.check(empty, 0.5).reason == "empty"
    jumped = sol(1, ("a", ecef_at(20_000, 0)), ("b", ecef_at(20_050, 0)), ("u4", ecef_at(10, 0)))
    assert g.check(jumped, 0.6).reason == "no-continuing-vehicle"
    genuine = g.check(sol(1, ("a", ecef_at(10, 0)), ("b", ecef_at(60, 0))), 1.0)
    assert genuine.accepted and g.run is not None and g.run.epoch == T0 + 1.0
    # a new vehicle beside a tracked one is taken (a vehicle joining the fleet)
    v = g.check(sol(2, ("a", ecef_at(20, 0)), ("u4", ecef_at(10, 0))), 2.0)
    assert v.solution is not None and [x.vehicle_id for x in v.solution.vehicles] == ["a", "u4"]
    # the first solution of a run may be empty (nothing to continue yet)
    assert SolutionGate(FLEET).check(empty, 0.0).accepted


def test_new_generation_only_after_the_current_one_went_quiet() -> None:
    g = SolutionGate(FLEET, restart_quiet_s=3.0)
    for k in range(3):
        assert g.check(sol(k), float(k)).accepted
    forged = sol(0, gen="badbadbadbad")
    assert g.check(forged, 2.5).reason == "new-generation"  # the genuine server is publishing
    assert g.check(sol(3), 3.0).accepted and g.resets == 0
    # a real restart: the old server stopped at 3.0, the new one (another generation) starts at 0
    restarted = sol(0, gen="0123456789abcdef")
    assert g.check(restarted, 4.0).reason == "new-generation"  # too soon: held
    assert g.release(5.0) is None
    v = g.release(6.5)  # quiet for 3 s: the held first solution of the new run is taken
    assert v is not None and v.accepted and v.reset and g.generation == "0123456789abcdef"
    assert g.check(sol(1, gen="0123456789abcdef"), 7.0).accepted and g.resets == 1
    # and the old generation is now the foreign one
    assert g.check(sol(4), 7.5).reason == "new-generation"


def test_a_server_that_withdrew_its_token_is_followed_by_its_successor_at_once() -> None:
    """The run's server withdrew its liveliness token (a clean stop): the restarted server's first
    solution is taken when it comes, not after the quiet time; held before that, released then."""
    g = SolutionGate(FLEET, restart_quiet_s=3.0)
    for k in range(3):
        assert g.check(sol(k), float(k)).accepted
    g.server_gone()  # at 2.1
    restarted = sol(0, gen="0123456789abcdef")
    v = g.check(restarted, 2.6)  # 0.6 s after the old server's last solution
    assert v.accepted and v.reset and g.generation == "0123456789abcdef"
    # the other order: the new run's first solution before the old token's withdrawal
    g = SolutionGate(FLEET, restart_quiet_s=3.0)
    for k in range(3):
        g.check(sol(k), float(k))
    assert g.check(restarted, 2.5).reason == "new-generation" and g.release(2.6) is None
    g.server_gone()
    v = g.release(2.7)
    assert v is not None and v.accepted and v.reset


def test_a_held_message_the_run_went_on_after_is_never_released() -> None:
    """A forged generation held while the genuine server still published is a forgery, not the
    successor: when that server later stops, it must not be taken (found by the insecure-bus
    attack of tests/fleet/test_hostile_fleet.py, whose server stops after the attack)."""
    g = SolutionGate(FLEET, restart_quiet_s=3.0)
    g.check(sol(0), 0.0)
    assert g.check(sol(0, gen="badbadbadbad"), 0.5).reason == "new-generation"  # held
    for k in range(1, 4):
        assert g.check(sol(k), float(k)).accepted  # the genuine run goes on
    g.server_gone()
    assert g.release(3.5) is None and g.held is None and g.generation == GEN
    assert g.release(10.0) is None  # nor after the quiet time


def test_the_same_run_coming_back_undoes_server_gone() -> None:
    """A router restart withdraws and re-announces every token, and a crashed server resumes its
    generation: once its run continues, a foreign generation must wait for the quiet time again."""
    g = SolutionGate(FLEET, restart_quiet_s=3.0)
    for k in range(3):
        g.check(sol(k), float(k))
    g.server_gone()
    assert g.check(sol(3), 3.0).accepted  # the same run goes on
    assert g.check(sol(0, gen="badbadbadbad"), 3.5).reason == "new-generation"


def test_gate_set_ends_a_run_only_when_its_server_s_token_goes() -> None:
    """Regions: server s2's token ends s2's run, not s1's. The single server's gate (its solutions
    do not name a server) ends once no fusion token is left. Other roles' tokens change nothing."""
    gs = GateSet(FLEET, restart_quiet_s=3.0)
    for server in ("s1", "s2", ""):
        assert gs.check(server, sol(0), 0.0).accepted
    for ident in ("s1", "s2", "0"):
        assert gs.presence(f"coplane/v1/{FLEET}/alive/fusion/{ident}", True)
    assert not gs.presence(f"coplane/v1/{FLEET}/alive/agent/a", False)
    assert not gs.presence("not/a/token/key", False)
    gs.presence(f"coplane/v1/{FLEET}/alive/fusion/s2", False)
    new = sol(0, gen="0123456789abcdef")
    assert gs.check("s2", new, 0.5).accepted
    assert gs.check("s1", new, 0.5).reason == "new-generation"
    assert gs.check("", new, 0.5).reason == "new-generation"  # s1 and 0 are still up
    gs.presence(f"coplane/v1/{FLEET}/alive/fusion/s1", False)
    gs.presence(f"coplane/v1/{FLEET}/alive/fusion/0", False)
    # the new generation each of them held is taken now, long before the quiet time
    assert gs.release(0.6) is not None and gs.release(0.6) is not None and gs.release(0.6) is None
    assert all(g.generation == "0123456789abcdef" for g in gs.gates.values())


def test_resumed_server_same_generation_republish_is_a_silent_repeat() -> None:
    g = SolutionGate(FLEET)
    for k in range(4):
        g.check(sol(k), float(k))
    # kill -9, resume: the same generation, the last solution once more, then onwards
    assert g.check(sol(3), 20.0).reason == "repeat"
    assert g.check(sol(4), 21.0).accepted and g.resets == 0


def test_a_forged_head_is_dropped_when_nobody_continues_it() -> None:
    g = SolutionGate(FLEET, resync_s=10.0)
    assert g.check(sol(100), 0.0).accepted  # a forged first message, 100 s ahead of the fleet
    for k in range(1, 12):
        v = g.check(sol(float(k)), float(k))
        if k <= 10:
            assert v.reason == "stale"
        else:
            assert v.accepted and v.reset  # 10 s of only older epochs: follow the stream
    assert g.check(sol(12), 12.0).accepted


def test_expect_bounds_a_fresh_gate_and_forgives_a_gap() -> None:
    g = SolutionGate(FLEET, max_ahead_s=900.0)
    t = T0 + 5.0
    assert g.check(sol(5 + WEEK_S), 0.0, expect=t).reason == "too-far-ahead"  # even as the first one
    assert g.check(sol(5), 0.0, expect=t).accepted
    # a one-hour recording gap: the lockstep agent waits for exactly that epoch
    assert g.check(sol(5 + 3600), 0.1, expect=T0 + 5.0 + 3600).accepted


def _collector(tmp_path: Path) -> Collector:
    """A collector without its bus node (its solution handler is what is tested)."""
    c = Collector.__new__(Collector)
    c.gate = GateSet(FLEET, method="pc", vehicles=["a", "b"])
    c.stream = SolutionLog(tmp_path / "s.sqlite", synchronous="NORMAL")
    c.run = MethodRun("pc", 0.0)
    c.lock = Lock()
    c.epochs = 0
    c.bad = 0
    c.listeners = []
    return c


def test_collector_writes_only_trusted_solutions(tmp_path: Path) -> None:
    c = _collector(tmp_path)
    genuine = [sol(k, ("a", ecef_at(8.0 * k, 0)), ("b", ecef_at(8.0 * k, 20))) for k in range(5)]
    for k, s in enumerate(genuine):
        c._on_solution(encode(s))
        if k == 2:
            week_ago = s.model_copy(update={"epoch": s.epoch.model_copy(update={"week": T0.week - 1})})
            c._on_solution(encode(week_ago))
            c._on_solution(encode(sol(3, ("a", (0.0, 0.0, 0.0)))))  # off the Earth
            c._on_solution(encode(sol(2, ("a", ecef_at(0, 0)))))  # a repeat of epoch 2
    c._on_solution(encode(sol(5, ("a", ecef_at(5000, 0)), ("b", ecef_at(40, 20)))))  # a jumps 5 km
    assert c.epochs == 6
    assert c.untrusted == {"stale": 1, "off-earth": 1, "repeat": 1, "vehicle-jump": 1}
    assert c.stream is not None
    logged = c.stream.solutions()
    c.stream.close()
    assert [s.seq for s in logged] == [0, 1, 2, 3, 4, 5]
    assert [v.vehicle_id for v in logged[-1].vehicles] == ["b"]  # what was taken is what is stored
    assert logged[:5] == genuine


@pytest.mark.parametrize("gen", [None, GEN])
def test_generation_none_is_a_generation_too(gen: str | None) -> None:
    """Hand-made or older solutions carry no generation: they are one run of their own."""
    g = SolutionGate(FLEET)
    assert g.check(sol(0, gen=gen), 0.0).accepted
    assert g.check(sol(1, gen=gen), 1.0).accepted and g.generation == gen
    assert GpsTime(T0.week, T0.tow + 1) == g.run.epoch if g.run else False
