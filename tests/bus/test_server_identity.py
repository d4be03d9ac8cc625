"""Fusion servers with identities of their own (docs/bus.md, Security): `fusion-<id>` names,
the keys a server puts on, the grants that hold it to them, and the start check that refuses a
server whose identity the router would silence."""

from __future__ import annotations

from pathlib import Path

import pytest

from coplane.bus import BusSecurity, KeySpace
from coplane.bus.acl import grants
from coplane.bus.certs import common_name, init_certs, load_cert
from coplane.bus.config import servers_in, vehicles_in
from coplane.bus.security import check_identity, check_server_identity, server_identity, server_of_identity
from coplane.errors import ConfigError
from coplane.fleet.launcher import fleet_services, server_ids
from coplane.sim.generate import bundled_default_path


def test_identity_names() -> None:
    assert server_identity("s1") == "fusion-s1" and server_of_identity("fusion-s1") == "s1"
    assert server_of_identity("fusion") is None and server_of_identity("vehicle-s1") is None
    assert check_identity("fusion-s1") == "fusion-s1"
    for bad in ("fusion-", "fusion-a/b", "fusion-" + "x" * 33):
        assert server_of_identity(bad) is None
        with pytest.raises(ConfigError):
            check_identity(bad)
    with pytest.raises(ConfigError, match="invalid server id"):
        server_identity("a/b")


def test_keys_name_the_server() -> None:
    k = KeySpace("f1")
    one, s1 = k.server_keys(None), k.server_keys("s1")
    assert (one.solution, one.diagnostics, one.tiles) == (k.solution, k.diagnostics, k.map_tiles)
    assert (s1.solution, s1.diagnostics, s1.tiles) == (
        "coplane/v1/f1/solution/s1",
        "coplane/v1/f1/diagnostics/s1",
        "coplane/v1/f1/map/tiles/s1",
    )
    assert KeySpace.server_of_tiles_key(s1.tiles) == "s1" and KeySpace.server_of_tiles_key(one.tiles) == ""
    for not_tiles in (s1.solution, f"{s1.tiles}/x", "coplane/v1/f1/map", "x"):
        assert KeySpace.server_of_tiles_key(not_tiles) is None


def test_a_servers_grants_name_only_its_own_keys() -> None:
    """Whatever `fusion-s1` may send (puts, tokens, queryables, replies) is under its own keys; what
    it hears is what the shared `fusion` hears."""
    g = grants(["u1"], "f1", ["s1", "s2"])
    sent = {key for flow, _, keys in g["fusion-s1"] if flow == "ingress" for key in keys}
    heard = {(flow, m, keys) for flow, m, keys in g["fusion-s1"] if not (flow == "ingress" and "put" in m)}
    assert "coplane/v1/f1/solution/s1" in sent and "coplane/v1/f1/alive/fusion/s1" in sent
    assert not any("s2" in key for key in sent)
    puts = {key for flow, m, keys in g["fusion-s1"] if flow == "ingress" and "put" in m for key in keys}
    assert puts == {"coplane/v1/f1/solution/s1", "coplane/v1/f1/diagnostics/s1", "coplane/v1/f1/map/tiles/s1"}
    tokens = {
        key
        for flow, m, keys in g["fusion-s1"]
        if flow == "ingress" and "liveliness_token" in m
        for key in keys
    }
    assert tokens == {"coplane/v1/f1/alive/fusion/s1", "coplane/v1/f1/map/tiles/s1/@adv/**"}
    shared_heard = {(flow, m, keys) for flow, m, keys in g["fusion"] if flow == "egress"}
    assert {h for h in heard if h[0] == "egress"} == shared_heard
    assert "fusion-s1" not in grants(["u1"], "f1")  # no server ids, no per-server subjects


def test_certificates_for_servers(tmp_path: Path) -> None:
    r = init_certs(tmp_path, ["u1"], servers=["s1", "s2"])
    assert r.created == ["router", "fusion", "api", "monitor", "fusion-s1", "fusion-s2", "vehicle-u1"]
    assert common_name(load_cert(tmp_path / "fusion-s2.crt")) == "fusion-s2"
    assert servers_in(tmp_path) == ["s1", "s2"] and vehicles_in(tmp_path) == ["u1"]
    assert init_certs(tmp_path, ["u1"], servers=["s1", "s3"]).created == ["fusion-s3"]


def test_a_server_refuses_an_identity_that_cannot_speak_for_it(tmp_path: Path) -> None:
    sec = BusSecurity(certs=tmp_path)
    check_server_identity(sec.as_identity("fusion"), None)  # the shared one serves any server
    check_server_identity(sec.as_identity("fusion"), "s2")
    check_server_identity(sec.as_identity("fusion-s2"), "s2")
    check_server_identity(BusSecurity(insecure=True, identity="api"), None)  # no identities
    with pytest.raises(ConfigError, match="belongs to server s2, not to --server_id s1"):
        check_server_identity(sec.as_identity("fusion-s2"), "s1")
    with pytest.raises(ConfigError, match="--regions true --server_id s2"):
        check_server_identity(sec.as_identity("fusion-s2"), None)
    with pytest.raises(ConfigError, match="needs the bus identity"):
        check_server_identity(sec.as_identity("api"), None)


def test_the_launcher_gives_each_server_its_identity() -> None:
    rec = bundled_default_path()
    assert server_ids(1) == [] and server_ids(3) == ["s1", "s2", "s3"]
    one = [
        s
        for s in fleet_services(rec, "pc", "lockstep", 1.0, "tcp/x:1", ["u1"], False)
        if s.module.endswith("fusion_server")
    ]
    assert [s.identity for s in one] == ["fusion"] and "--server_id" not in one[0].args
    three = [
        s
        for s in fleet_services(rec, "pc", "lockstep", 1.0, "tcp/x:1", ["u1"], False, servers=3)
        if s.module.endswith("fusion_server")
    ]
    assert [s.identity for s in three] == ["fusion-s1", "fusion-s2", "fusion-s3"]
    assert [s.args[s.args.index("--server_id") + 1] for s in three] == ["s1", "s2", "s3"]


def test_a_fusion_server_stops_at_start_with_another_servers_identity(tmp_path: Path) -> None:
    """`FusionServer.run` checks its identity before it opens anything: with server s2's certificate
    it will not run as server s1, nor as the fleet's one server."""
    from coplane.bus import use_security
    from coplane.fusion_server.server import FusionServer
    from coplane.fusion_server.settings import FusionSettings
    from coplane.sim import ensure_default_recording

    rec = ensure_default_recording()
    with use_security(BusSecurity(certs=tmp_path, identity="fusion-s2")):
        for kw in ({"regions": True, "server_id": "s1"}, {}):
            server = FusionServer(FusionSettings(recording=rec, db="none", map="none", **kw))
            with pytest.raises(ConfigError, match="fusion-s2"):
                server.run()
