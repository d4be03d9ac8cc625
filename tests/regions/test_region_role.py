"""A fusion server's region role, the region keys and the consumers' per-server gates (issue 16):
the decisions every server must make alike, without the bus."""

from __future__ import annotations

import math

import numpy as np

from coplane.bus import KeySpace
from coplane.bus.gates import MAX_SERVERS, GateSet
from coplane.fusion_server.regions import MOVE_GRACE_S, RegionRole
from coplane.geo import geodetic_to_ecef
from coplane.gtime import GpsTime
from coplane.messages import DiagnosticsMessage, NodeMessage, SppReport, VehicleCounters, merge_diagnostics
from coplane.regions import RegionConfig, owner, region_of_ecef, shard_of
from coplane.roadmap import TileKey, tile_of_ecef

K = KeySpace("f")
CFG = RegionConfig(size_m=1000.0, margin_m=400.0)
T = GpsTime(2320, 1000.0)


def _role(me: str, servers: list[str]) -> RegionRole:
    r = RegionRole(me, K, CFG, window_s=10.0, expected_servers=len(servers))
    for s in servers:
        r.server_presence(s, True)
    return r


def _msg(vid: str, ranges_to: tuple[str, ...] = (), at: np.ndarray | None = None) -> NodeMessage:
    """A minimal node message (only the fields region selection reads)."""
    spp = SppReport.model_construct(ok=at is not None, position_ecef_m=None if at is None else tuple(at))
    return NodeMessage.model_construct(
        vehicle_id=vid, ranges=[type("R", (), {"to": to})() for to in ranges_to], spp=spp
    )


def _east(m: float) -> np.ndarray:
    lat, lon = math.radians(39.98), math.radians(116.31)
    return geodetic_to_ecef(lat, lon + m / (6371000.0 * math.cos(lat)), 50.0)


def _boundary_between(servers: list[str]) -> float:
    """An east offset (m) where the region changes and the two regions have different owners."""
    e = 0.0
    while True:
        a, b = region_of_ecef(_east(e), CFG), region_of_ecef(_east(e + 1.0), CFG)
        if a != b and owner(shard_of(a, 64), servers) != owner(shard_of(b, 64), servers):
            return e
        e += 1.0


def _regions_owned_by(servers: list[str], n: int = 2) -> dict[str, list[str]]:
    """Some region names per server, by the rule every process applies."""
    out: dict[str, list[str]] = {s: [] for s in servers}
    i = 0
    while any(len(v) < n for v in out.values()):
        r = f"r{i}c0"
        out[owner(shard_of(r, CFG.shards), servers) or ""].append(r)
        i += 1
    return out


def test_keys_name_vehicle_region_and_home() -> None:
    node = K.region_node(5, "r1c2", "u1")
    copy = K.region_copy(7, "r1c3", "u1", "r1c2")
    assert KeySpace.vehicle_of_node_key(node) == "u1" == KeySpace.vehicle_of_node_key(copy)
    assert KeySpace.region_of_node_key(node) == (5, "r1c2", "r1c2")
    assert KeySpace.region_of_node_key(copy) == (7, "r1c3", "r1c2")
    assert KeySpace.region_of_node_key(K.node("u1")) is None
    assert KeySpace.vehicle_of_node_key(f"{K.prefix}/shard/5/region/r1/vehicle/u1/near") is None
    assert KeySpace.server_of_solution_key(K.solution) == ""
    assert KeySpace.server_of_solution_key(K.server_solution("s2")) == "s2"


def test_each_vehicle_is_answered_by_its_own_regions_server_and_boundary_clusters_stay_whole() -> None:
    servers = ["s1", "s2"]
    e = _boundary_between(servers)
    pos = {"u1": _east(e - 100.0), "u2": _east(e + 100.0), "u3": _east(e + 900.0), "u4": _east(e + 300.0)}
    ra, rb = region_of_ecef(pos["u1"], CFG), region_of_ecef(pos["u2"], CFG)
    s_a = owner(shard_of(ra, 64), servers)
    roles = {s: _role(s, servers) for s in servers}
    # u1 in A, u2 in B 200 m away, ranging with each other; u3 alone deep in B
    keys = {
        "u1": K.region_node(shard_of(ra, 64), ra, "u1"),
        "u2": K.region_node(shard_of(rb, 64), rb, "u2"),
        "u3": K.region_node(shard_of(rb, 64), rb, "u3"),
    }
    msgs = {
        "u1": _msg("u1", ("u2",), pos["u1"]),
        "u2": _msg("u2", ("u1",), pos["u2"]),
        "u3": _msg("u3", (), pos["u3"]),
    }
    s_b = "s2" if s_a == "s1" else "s1"
    chosen = {}
    for s, role in roles.items():
        for vid, key in keys.items():
            role.saw_node(vid, key, 0.0, T, tuple(pos[vid]))
        chosen[s] = role.select(T, msgs, [("u1", "u2")])
    # both sides solve the boundary cluster whole (its range kept); each answers its own vehicles
    assert set(chosen[s_a].solve) == {"u1", "u2"} and chosen[s_a].answer == {"u1"}
    assert set(chosen[s_b].solve) == {"u1", "u2", "u3"} and chosen[s_b].answer == {"u2", "u3"}
    assert chosen[s_a].answer.isdisjoint(chosen[s_b].answer)
    assert chosen[s_a].answer | chosen[s_b].answer == set(msgs)
    assert sorted(chosen[s_a].others) == ["u2", "u3"] and sorted(chosen[s_b].others) == ["u1"]
    # A's server waits for u2 too (linked to its u1 and within the margin of A)
    assert roles[s_a].awaited({"u1", "u2", "u3"}, {}) == {"u1", "u2"}
    # a copy for A of a vehicle whose own region A's server also owns is skipped
    assert roles[s_a].own_copy(K.region_copy(shard_of(rb, 64), rb, "u1", ra))
    assert not roles[s_b].own_copy(K.region_copy(shard_of(rb, 64), rb, "u1", ra))
    # a cluster of other regions' vehicles only is not solved here
    only_a = roles[s_b].select(T, {"u1": msgs["u1"]}, [])
    assert not only_a.solve and not only_a.answer and only_a.others == ["u1"]


def test_the_region_of_the_epoch_decides_not_a_later_message() -> None:
    servers = ["s1", "s2"]
    owned = _regions_owned_by(servers)
    ra, rb = owned["s1"][0], owned["s2"][0]
    role = _role("s1", servers)
    role.saw_node("u1", K.region_node(shard_of(ra, 64), ra, "u1"), 0.0, T)
    role.saw_node("u1", K.region_node(shard_of(rb, 64), rb, "u1"), 0.1, T + 1.0)  # next epoch, moved
    assert role.select(T, {"u1": _msg("u1")}, []).answer == {"u1"}
    assert role.select(T + 1.0, {"u1": _msg("u1")}, []).answer == set()


def test_a_server_going_away_changes_ownership_and_subscriptions() -> None:
    role = _role("s1", ["s1", "s2", "s3"])
    before = set(role.shards)
    assert role.wanted() == {K.shard_nodes(s) for s in before}
    assert role.server_presence("s2", False)
    assert role.shards > before and role.dirty
    assert not role.server_presence("s1", False)  # its own token: nothing to do


def test_gates_are_per_server_and_bounded() -> None:
    g = GateSet("f")
    for i in range(MAX_SERVERS):
        assert g.gate(f"s{i}") is not None
    assert g.gate("one-more") is None


def test_merged_diagnostics_add_up() -> None:
    a = DiagnosticsMessage(
        fleet="f",
        method="pc",
        pace="lockstep",
        epochs_solved=10,
        vehicles={"u1": VehicleCounters(received=10, used=10, online=True)},
        server="s1",
        shards=[0, 2],
        regions={"r1c1": ["u1"]},
    )
    b = DiagnosticsMessage(
        fleet="f",
        method="pc",
        pace="lockstep",
        epochs_solved=4,
        vehicles={"u1": VehicleCounters(received=3, elsewhere=3), "u2": VehicleCounters(received=4, used=4)},
        server="s2",
        shards=[1],
    )
    m = merge_diagnostics([a, b])
    assert m.vehicles["u1"].received == 13 and m.vehicles["u1"].used == 10 and m.vehicles["u1"].online
    assert m.vehicles["u1"].elsewhere == 3 and m.vehicles["u2"].used == 4
    assert m.epochs_solved == 10 and m.shards == [0, 1, 2] and m.servers == ["s1", "s2"]


def test_a_tile_has_one_writer_once_the_servers_have_settled() -> None:
    """Whose copy of a road-map tile a server takes (docs/scale.md, "The road map across servers"):
    anyone's while the live servers have just changed, then only its region's owner's."""
    a, b = _role("s1", ["s1", "s2"]), _role("s2", ["s1", "s2"])
    key = tile_of_ecef(_east(100.0), 20.0)
    assert a.tile_writers(key, 20.0) is None  # just started: the others may not be seen yet
    for r in (a, b):
        r.servers_changed_at -= MOVE_GRACE_S + 1.0
    writer = owner(shard_of(region_of_ecef(_east(100.0), CFG), CFG.shards), ["s1", "s2"])
    assert a.tile_writers(key, 20.0) == b.tile_writers(key, 20.0) == {writer}
    assert (writer == "s1") == a.owns_tile(key, 20.0)
    a.server_presence("s2", False)  # s2 went: a grace time, then s1 writes everything
    assert a.tile_writers(key, 20.0) is None
    a.servers_changed_at -= MOVE_GRACE_S + 1.0
    assert a.tile_writers(key, 20.0) == {"s1"} and a.tile_writers(TileKey(5, 7), 20.0) == {"s1"}
