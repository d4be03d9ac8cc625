"""A vehicle agent fed genuine and forged solutions (issue 13): forged positions never reach its
plane history (they cut u3's usable planes from 19 epochs to 1 and pushed its error to 25 m).

The agent is built from a short simulated recording; its bus side is replaced by handing it
`Payload` events directly, and every solution its step ingests is recorded.
"""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from coplane.bus import Payload, decode, encode
from coplane.evaluate.runner import run_method
from coplane.geo import enu_to_ecef
from coplane.messages import EpochTime, NodeMessage, SolutionMessage, VehicleState
from coplane.recording.reader import open_recording
from coplane.sim.generate import simulate
from coplane.steps import gps_time
from coplane.vehicle_agent.agent import VehicleAgent
from coplane.vehicle_agent.settings import AgentSettings

GEN = "1234abcd1234abcd"


@pytest.fixture(scope="module")
def genuine(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[SolutionMessage]]:
    rec = simulate("urban-loop", tmp_path_factory.mktemp("rec") / "r", vehicles=3, duration_s=12, seed=3)
    sols: list[SolutionMessage] = []
    run_method(open_recording(rec), "pc", on_solution=lambda s, _m: sols.append(s), jobs=1)
    return rec, [s.model_copy(update={"generation": GEN}) for s in sols]


def _moved(vs: VehicleState, east_m: float) -> VehicleState:
    x, y, z = (float(c) for c in enu_to_ecef([east_m, 0.0, 0.0], vs.position_ecef_m))
    return vs.model_copy(update={"position_ecef_m": (x, y, z)})


def _forgeries(s: SolutionMessage) -> list[SolutionMessage]:
    """Valid messages a forger could put next to genuine solution `s`."""
    ep = s.epoch
    return [
        s.model_copy(update={"epoch": EpochTime(week=ep.week - 1, tow=ep.tow)}),  # a week earlier
        s.model_copy(update={"epoch": EpochTime(week=ep.week + 1, tow=ep.tow)}),  # a week ahead
        s.model_copy(update={"vehicles": [_moved(v, 5000.0) for v in s.vehicles]}),  # 5 km away
        s.model_copy(
            update={
                "vehicles": [v.model_copy(update={"position_ecef_m": (0.0, 0.0, 0.0)}) for v in s.vehicles]
            }
        ),
        s.model_copy(update={"method": "mci"}),
        s.model_copy(update={"generation": "feedfacefeedface"}),  # an invented server run
    ]


def test_agent_ingests_only_genuine_solutions(
    genuine: tuple[Path, list[SolutionMessage]], monkeypatch: pytest.MonkeyPatch
) -> None:
    rec, sols = genuine
    agent = VehicleAgent(AgentSettings(recording=rec, vehicle_id="u3", method="pc"))
    taken: list[SolutionMessage] = []
    monkeypatch.setattr(agent.step, "ingest", taken.append)
    key = agent.keys.solution
    for k, s in enumerate(sols):
        t = gps_time(s.epoch)
        order = [*_forgeries(s), s] if k else [s, *_forgeries(s)]  # then the forger gets in first
        for m in (*order, s):  # the last: a resend / the republish after a resume
            agent.ingest_one(Payload(key, encode(m)), expect=t)
    assert taken == sols  # every genuine solution, each once, nothing else
    n, u = len(sols), agent.untrusted
    assert u["stale"] == u["too-far-ahead"] == u["off-earth"] == u["wrong-method"] == n
    assert u["new-generation"] == n
    assert u["no-trusted-vehicle"] == n - 1 and u["vehicle-jump"] == 3 * (n - 1)  # 5 km, 3 vehicles
    assert u["repeat"] == n + 1  # the resends, and the 5 km one of the first epoch (after the genuine)


def test_plane_history_is_the_clean_runs(genuine: tuple[Path, list[SolutionMessage]]) -> None:
    """With the real step: u3's plane history after an attacked run is the clean run's."""
    rec, sols = genuine
    clean = VehicleAgent(AgentSettings(recording=rec, vehicle_id="u3", method="pc"))
    attacked = VehicleAgent(AgentSettings(recording=rec, vehicle_id="u3", method="pc"))
    for a in (clean, attacked):
        a.step.first_epoch = gps_time(sols[0].epoch)  # as if it had published its first epoch
    key = clean.keys.solution
    for k, s in enumerate(sols):
        t = gps_time(s.epoch)
        for m in [*_forgeries(s), s] if k else [s, *_forgeries(s)]:  # as above
            attacked.ingest_one(Payload(key, encode(m)), expect=t)
        clean.ingest_one(Payload(key, encode(s)), expect=t)
    assert attacked.ingested == clean.ingested == len(sols)
    assert attacked.step._last_fused is not None and clean.step._last_fused is not None
    assert attacked.step._last_fused[0] == clean.step._last_fused[0]
    assert (attacked.step._last_fused[1] == clean.step._last_fused[1]).all()
    assert len(attacked.step.history) == len(clean.step.history) > 0


class _QuietNode:
    """A bus node that delivers some events, then nothing (the server waits for the next epoch)."""

    def __init__(self, events: list[Payload]) -> None:
        self.events = list(events)
        self.puts: list[tuple[str, bytes]] = []

    def get(self, timeout: float | None = None) -> Payload | None:
        if self.events:
            return self.events.pop(0)
        time.sleep(timeout or 0.0)
        return None

    def put(self, key: str, payload: bytes) -> None:
        self.puts.append((key, payload))


def test_lockstep_agent_is_not_stalled_by_a_fast_server_restart(
    genuine: tuple[Path, list[SolutionMessage]],
) -> None:
    """The restarted server (a new generation) solves the awaited epoch once: the gate holds it
    while the old server was heard recently and the agent takes it once that one is quiet."""
    rec, sols = genuine
    agent = VehicleAgent(AgentSettings(recording=rec, vehicle_id="u3", method="pc"))
    gate = agent.gate.gate("")  # the single server's `solution` key
    assert gate is not None
    gate.restart_quiet_s = 0.3
    key = agent.keys.solution
    for s in sols[:3]:
        assert agent.ingest_one(Payload(key, encode(s)), expect=gps_time(s.epoch)) is not None
    t = gps_time(sols[3].epoch)
    restarted = sols[3].model_copy(update={"generation": "5ca1ab1e5ca1ab1e", "seq": 0})
    node = _QuietNode([Payload(key, encode(restarted))])
    t0 = time.monotonic()
    agent.wait_for_solution(t, node, [agent.keys.node("u3")], b"{}")  # type: ignore[arg-type]
    assert time.monotonic() - t0 < 5.0
    assert gate.generation == "5ca1ab1e5ca1ab1e" and gate.resets == 1
    assert agent.ingested == 4


class _LockstepNode(_QuietNode):
    """Answers each node message with the genuine solution of its epoch, except the third: the
    fleet goes on without the vehicle and the next solution this agent hears is two epochs later."""

    def __init__(self, sols: list[SolutionMessage], key: str) -> None:
        super().__init__([])
        self.by_epoch = {gps_time(s.epoch): s for s in sols}
        self.order = [gps_time(s.epoch) for s in sols]
        self.key, self.sent = key, []  # type: ignore[var-annotated]

    def __enter__(self) -> _LockstepNode:
        return self

    def __exit__(self, *exc: object) -> None:
        return None

    def drain(self) -> list[Payload]:
        out, self.events = self.events, []
        return out

    def put(self, key: str, payload: bytes) -> None:
        super().put(key, payload)
        t = gps_time(decode(NodeMessage, payload).epoch)
        if t in self.sent:
            return  # a resend
        self.sent.append(t)
        k = self.order.index(t)
        answer = self.by_epoch[self.order[k + 2 if k == 2 else k]]
        self.events.append(Payload(self.key, encode(answer)))


def test_a_lockstep_agent_the_fleet_left_behind_joins_at_the_fleet_s_epoch(
    genuine: tuple[Path, list[SolutionMessage]], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Released by a solution past its epoch, the agent skips the epochs already solved: sent, they
    would be late, and it would stay two epochs behind the fleet for good (seen with regions: the
    whole lockstep fleet stalled once every vehicle was behind)."""
    rec, sols = genuine
    agent = VehicleAgent(AgentSettings(recording=rec, vehicle_id="u3", method="pc", resend_s=30.0))
    node = _LockstepNode(sols, agent.keys.solution)
    monkeypatch.setattr(agent, "node", lambda: node)
    published = agent.run()
    order = node.order
    assert node.sent == [*order[:3], *order[5:]]  # epochs 3 and 4 were solved without it
    assert agent.skipped == 2 and published == len(order) - 2


def test_agent_takes_map_tiles_only_from_the_server_their_key_names(
    genuine: tuple[Path, list[SolutionMessage]],
) -> None:
    """A map method's agent: a tiles batch is taken from the key of the server it names (the single
    server's `map/tiles` names none) and dropped whole, counted, from another server's key."""
    import numpy as np

    from coplane.roadmap import RoadMapConfig, TileKey, TilePlane
    from coplane.steps.map_tiles import tiles_messages

    rec, _ = genuine
    agent = VehicleAgent(AgentSettings(recording=rec, vehicle_id="u3", method="pc-map", map_wait_s=0.0))
    assert agent.tiles is not None
    tile = TilePlane(
        key=TileKey(100, 7), h0_m=41.5, info=np.diag([40.0, 300.0, 300.0]), eta=np.array([4.0, 0.0, 0.0]),
        n_passes=4, n_points=40, version=3, updated_s=1.4e9,
    )  # fmt: skip
    says_s1 = tiles_messages(agent.fleet, [tile], RoadMapConfig(), 1, False, "s1")[0]
    agent.ingest_one(Payload(agent.keys.server_tiles("s2"), encode(says_s1)))
    agent.ingest_one(Payload(agent.keys.map_tiles, encode(says_s1)))
    assert TileKey(100, 7) not in agent.tiles.map.tiles
    assert agent.tiles.counts["rejected:wrong-sender"] == 2
    agent.ingest_one(Payload(agent.keys.server_tiles("s1"), encode(says_s1)))
    assert agent.tiles.map.tiles[TileKey(100, 7)].version == 3


def test_with_regions_only_the_owner_of_its_region_answers_for_the_vehicle(
    genuine: tuple[Path, list[SolutionMessage]], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Regions (docs/scale.md, "Boundaries"): a server's well-formed solution that speaks for this
    vehicle is taken only from the owner of the region the vehicle sent that epoch from, among
    the live servers; another server's is dropped (`not-owner`), one that does not name the
    vehicle is taken, and within the grace time after a change of the live servers any is."""
    from coplane.regions import owner, region_of_ecef, shard_of

    rec, sols = genuine
    agent = VehicleAgent(AgentSettings(recording=rec, vehicle_id="u3", method="pc", regions=True))
    assert agent.region is not None
    taken: list[SolutionMessage] = []
    monkeypatch.setattr(agent.step, "ingest", taken.append)
    cfg = agent.region.cfg
    u3 = next(v for v in sols[0].vehicles if v.vehicle_id == "u3")
    region = region_of_ecef(u3.position_ecef_m, cfg)
    live = {"s1", "s2"}
    home = owner(shard_of(region, cfg.shards), live)
    other = ({"s1", "s2"} - {home}).pop()
    for s in sols:
        agent.region.sent[gps_time(s.epoch)] = region  # as `keys_for` records each epoch sent
    for sid in live:
        agent.gate.server_token(sid, True)
    agent.gate.servers_changed = -1e9  # the live servers known long ago: no grace

    def as_server(s: SolutionMessage, sid: str, vehicles: list[str]) -> Payload:
        msg = s.model_copy(
            update={
                "server": sid,
                "answered": vehicles,
                "vehicles": [v for v in s.vehicles if v.vehicle_id in vehicles],
            }
        )
        return Payload(agent.keys.server_solution(sid), encode(msg))

    agent.ingest_one(as_server(sols[1], other, ["u1", "u2"]))  # the other server, its own vehicles
    agent.ingest_one(as_server(sols[2], other, ["u1", "u2", "u3"]))  # ... and u3 too
    agent.ingest_one(as_server(sols[3], home, ["u3"]))  # the owner answers for u3
    assert [(s.server, s.answered) for s in taken] == [(other, ["u1", "u2"]), (home, ["u3"])], agent.untrusted
    assert agent.untrusted["not-owner"] == 1
    agent.gate.server_token("s3", True)  # a server joins: the views may differ for a while
    agent.ingest_one(as_server(sols[4], other, ["u1", "u2", "u3"]))
    assert [(s.server, s.answered) for s in taken][-1] == (other, ["u1", "u2", "u3"])
    assert agent.untrusted["not-owner"] == 1
