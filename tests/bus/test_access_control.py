"""The secure bus through a live router: mutual TLS and access control by certificate common name.

One TLS + ACL router (in this process) and one session per identity; every identity x key x
operation that matters is tried (coplane.bus.probe). Unauthorised: 0 delivered. Authorised: every
one delivered. Clients without an acceptable certificate do not connect at all.
"""

from __future__ import annotations

from pathlib import Path

import pytest
import zenoh

from coplane.bus import BusSecurity, router_config
from coplane.bus.certs import init_certs
from coplane.bus.probe import allowed, anonymous_tls_config, client_config, probe_access, probe_connections
from coplane.fleet import free_port

FLEET = "f1"
VEHICLES = ["u1", "u2", "u3"]
# vehicle-u9 has a certificate from the fleet's CA but no grant: default deny
IDENTITIES = ["vehicle-u1", "vehicle-u2", "vehicle-u9", "fusion", "api", "monitor"]


@pytest.fixture(scope="module")
def secure_router(tmp_path_factory: pytest.TempPathFactory):
    root = tmp_path_factory.mktemp("acl")
    certs = root / "certs"
    init_certs(certs, [*VEHICLES, "u9"])
    ep = f"tls/127.0.0.1:{free_port()}"
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
    # the road map: only the fusion server puts tiles, the fleet's agents read them
    assert allowed("fusion", "map/tiles", "put", v) and not allowed("vehicle-u1", "map/tiles", "put", v)
    assert allowed("vehicle-u1", "map/tiles", "subscribe", v) and not allowed(
        "vehicle-u9", "map/tiles", "subscribe", v
    )


def test_every_identity_key_operation(secure_router: tuple[str, Path, Path]) -> None:
    ep, certs, _ = secure_router
    attempts = probe_access(ep, certs, FLEET, IDENTITIES, VEHICLES)
    leaked = [a for a in attempts if a.delivered and not a.allowed]
    missing = [a for a in attempts if a.allowed and not a.delivered]
    print(f"{len(attempts)} attempts, {sum(a.allowed for a in attempts)} authorised")
    assert not leaked, f"unauthorised messages delivered: {leaked}"
    assert not missing, f"authorised messages lost: {missing}"
    ops = {a.operation for a in attempts}
    assert ops == {"put", "token", "subscribe", "liveliness-subscribe"}
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
