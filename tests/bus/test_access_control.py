"""The secure bus through a live router: mutual TLS and access control by certificate common name.

One TLS + ACL router (in this process) and one session per identity; every identity x key x
operation that matters is tried (coplane.bus.probe). Unauthorised: 0 delivered. Authorised: every
one delivered. Clients without an acceptable certificate do not connect at all.
"""

from __future__ import annotations

import contextlib
import time
from pathlib import Path
from typing import Any

import pytest
import zenoh

from coplane.bus import (
    BusNode,
    BusSecurity,
    KeySpace,
    Payload,
    Presence,
    Publication,
    Request,
    Subscription,
    router_config,
    session_config,
)
from coplane.bus.certs import init_certs
from coplane.bus.probe import (
    SETTLE_S,
    allowed,
    anonymous_tls_config,
    client_config,
    probe_access,
    probe_connections,
)
from coplane.fleet import free_port

FLEET = "f1"
VEHICLES = ["u1", "u2", "u3"]
SERVERS = ["s1", "s2"]  # fusion servers with identities of their own (regions)
# vehicle-u9 has a certificate from the fleet's CA but no grant: default deny
IDENTITIES = ["vehicle-u1", "vehicle-u2", "vehicle-u9", "fusion", "fusion-s1", "fusion-s2", "api", "monitor"]


@pytest.fixture(scope="module")
def secure_router(tmp_path_factory: pytest.TempPathFactory):
    root = tmp_path_factory.mktemp("acl")
    certs = root / "certs"
    init_certs(certs, [*VEHICLES, "u9"], servers=SERVERS)
    ep = f"tls/127.0.0.1:{free_port()}"
    # the servers' identities from the folder, as a router started by `coplane fleet` finds them
    router = zenoh.open(router_config([ep], BusSecurity(certs=certs), vehicles=VEHICLES, fleet=FLEET))
    try:
        yield ep, certs, root
    finally:
        router.close()


def test_policy_table() -> None:
    """The policy the probe checks against, spelled out for the cases the issue names."""
    v = VEHICLES
    assert allowed("vehicle-u1", "vehicle/u1/node", "put", v)
    assert not allowed("vehicle-u1", "vehicle/u2/node", "put", v)
    assert not allowed("vehicle-u1", "solution", "put", v)
    assert not allowed("vehicle-u1", "alive/fusion/0", "token", v)
    assert not allowed("vehicle-u1", "alive/agent/u2", "token", v)
    assert not allowed("vehicle-u9", "vehicle/u9/node", "put", v)  # not one of the fleet's vehicles
    assert allowed("fusion", "solution", "put", v) and allowed("fusion", "alive/fusion/0", "token", v)
    assert not any(allowed("api", k, "put", v) for k in ("solution", "diagnostics", "vehicle/u1/node"))
    # the road map: only the fusion server puts tiles; agents ask for theirs (`test_area_query`)
    assert allowed("fusion", "map/tiles", "put", v) and not allowed("vehicle-u1", "map/tiles", "put", v)
    assert not allowed("vehicle-u1", "map/tiles", "subscribe", v)
    # a server's own identity speaks for it alone; it hears what every fusion server hears
    for key in ("solution/s1", "diagnostics/s1", "map/tiles/s1"):
        assert allowed("fusion-s1", key, "put", v) and not allowed("fusion-s2", key, "put", v)
    assert not any(allowed("fusion-s1", k, "put", v) for k in ("solution", "diagnostics", "map/tiles"))
    assert allowed("fusion-s1", "alive/fusion/s1", "token", v)
    assert not allowed("fusion-s1", "alive/fusion/s2", "token", v)
    assert allowed("fusion-s2", "vehicle/u1/node", "subscribe", v)
    assert allowed("fusion-s2", "map/tiles/s1", "subscribe", v)


def test_every_identity_key_operation(secure_router: tuple[str, Path, Path]) -> None:
    ep, certs, _ = secure_router
    attempts = probe_access(ep, certs, FLEET, IDENTITIES, VEHICLES)
    leaked = [a for a in attempts if a.delivered and not a.allowed]
    missing = [a for a in attempts if a.allowed and not a.delivered]
    print(f"{len(attempts)} attempts, {sum(a.allowed for a in attempts)} authorised")
    assert not leaked, f"unauthorised messages delivered: {leaked}"
    assert not missing, f"authorised messages lost: {missing}"
    ops = {a.operation for a in attempts}
    assert ops == {"put", "token", "subscribe", "liveliness-subscribe", "answer", "ask"}
    assert sum(not a.allowed for a in attempts) >= 50  # the matrix really tries the forbidden cases


def test_clients_without_an_acceptable_certificate_cannot_connect(
    secure_router: tuple[str, Path, Path],
) -> None:
    ep, certs, root = secure_router
    foreign = root / "foreign"
    init_certs(foreign, ["u1"])  # the same common names, from another CA
    attempts = probe_connections(
        {
            "no certificate": anonymous_tls_config(ep, certs / "ca.crt"),
            "another CA's fusion certificate": client_config(
                ep, BusSecurity(certs=foreign, identity="fusion")
            ),
            "plain TCP": client_config("tcp/" + ep.split("/", 1)[1], BusSecurity(insecure=True)),
        }
    )
    assert not any(a.delivered for a in attempts), attempts
    # and a good certificate does connect (the probe is not failing for some other reason)
    assert probe_connections({"fusion": client_config(ep, BusSecurity(certs=certs, identity="fusion"))})[
        0
    ].delivered


def test_a_server_identity_reaches_the_consumers_wildcards(secure_router: tuple[str, Path, Path]) -> None:
    """A fusion server with its own identity publishes as the services do (declared publishers,
    the tiles with a history cache): an agent subscribed to every server's solutions
    (`solution/**`) gets them, and another server subscribed to every server's tiles
    (`map/tiles/**`, with history) gets them from the cache. The
    publishers send only once the router forwards the consumers' wildcard declarations to them,
    which the probe's plain puts above do not need; and one server's identity cannot declare
    another's liveliness token or put on its keys."""
    ep, certs, _ = secure_router
    k = KeySpace(FLEET)
    own = k.server_keys("s1")
    base = BusSecurity(certs=certs)

    def node(identity: str, **kw: Any) -> BusNode:
        return BusNode(session_config("client", [ep], security=base.as_identity(identity)), **kw)

    server = node(
        "fusion-s1",
        token=k.alive("fusion", "s1"),
        publish=[
            Publication(own.solution, must_deliver=True),
            Publication(own.tiles, must_deliver=True, history=4),
        ],
    )
    with server:
        server.put(own.tiles, b"cached")  # before the agent exists: only the cache can give it
        time.sleep(0.3)
        agent = node(
            "vehicle-u1",
            subscribe=[Subscription(k.all_solutions), Subscription(k.all_alive("fusion"), liveliness=True)],
        )
        peer = node("fusion-s2", subscribe=[Subscription(k.all_map_tiles, history=True)])
        with agent, peer, node("fusion-s2", publish=[Publication(own.solution)]) as impostor:
            time.sleep(0.5)
            server.put(own.solution, b"live")
            impostor.put(own.solution, b"forged")  # a well-formed put from the wrong server
            got: set[tuple[str, bytes]] = set()
            presence: set[str] = set()
            deadline = time.monotonic() + 5.0
            while (
                time.monotonic() < deadline and not {(own.solution, b"live"), (own.tiles, b"cached")} <= got
            ):
                for ev in (agent.get(timeout=0.1), peer.poll()):
                    if isinstance(ev, Payload):
                        got.add((ev.key, ev.data))
                    elif isinstance(ev, Presence) and ev.alive:
                        presence.add(ev.key)
            time.sleep(SETTLE_S)
            for ev in [*agent.drain(), *peer.drain()]:
                if isinstance(ev, Payload):
                    got.add((ev.key, ev.data))
    assert (own.solution, b"live") in got and (own.tiles, b"cached") in got, got
    assert (own.solution, b"forged") not in got
    assert k.alive("fusion", "s1") in presence


def test_area_query_is_answered_by_servers_alone(secure_router: tuple[str, Path, Path]) -> None:
    """The road map's area queries (docs/roadmap.md, "Tiles on the bus"): an agent's query for
    `map/tiles/**` reaches a server's queryable on its own tiles key and the answer comes back.
    A vehicle cannot declare a queryable there to answer in a server's name, one server's
    identity cannot answer on another's key, and a vehicle outside the fleet cannot ask."""
    ep, certs, _ = secure_router
    k = KeySpace(FLEET)
    base = BusSecurity(certs=certs)

    def node(identity: str, **kw: Any) -> BusNode:
        return BusNode(session_config("client", [ep], security=base.as_identity(identity)), **kw)

    s1 = k.server_keys("s1").tiles
    answerers = {
        "fusion-s1": node("fusion-s1", serve=[s1]),
        "fusion-s2 on s1's key": node("fusion-s2", serve=[s1]),
        "vehicle-u2": node("vehicle-u2", serve=[s1]),
    }
    askers = {"vehicle-u1": node("vehicle-u1"), "vehicle-u9": node("vehicle-u9")}
    got: dict[str, set[bytes]] = {name: set() for name in askers}
    order: dict[str, list[str]] = {name: [] for name in askers}
    with contextlib.ExitStack() as stack:
        for n in [*answerers.values(), *askers.values()]:
            stack.enter_context(n)
        time.sleep(0.5)
        for tag, asker in enumerate(askers.values()):
            asker.request(f"{k.all_map_tiles}?box=0,1,0,1", tag, timeout_s=2.0)
        deadline = time.monotonic() + 3.0
        while time.monotonic() < deadline:
            for name, answerer in answerers.items():
                while (ev := answerer.poll()) is not None:
                    if isinstance(ev, Request):
                        BusNode.answer(ev, s1, [name.encode()])
            for name, asker in askers.items():
                while (ev := asker.poll()) is not None:
                    order[name].append(type(ev).__name__)
                    if isinstance(ev, Payload):
                        got[name].add(ev.data)
            time.sleep(0.05)
    assert got["vehicle-u1"] == {b"fusion-s1"}, got
    assert got["vehicle-u9"] == set(), got
    # the end of a request comes after its answers, once the servers finished (not the timeout)
    assert order["vehicle-u1"] == ["Payload", "Answered"], order
