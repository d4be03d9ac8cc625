"""Zenoh session configurations for the services, the fleet launcher and the routers.

Security comes from `BusSecurity` (coplane.bus.security): when it names a certificates folder,
every client connects over TLS with its own certificate (mutual TLS) and the router listens on TLS
only, demands a client certificate signed by the fleet's CA and applies the access control of
coplane.bus.acl. Callers pass `tcp/...` or `tls/...` endpoints alike; a secure config turns
`tcp/` into `tls/` (a plain connection to a TLS router would be refused anyway), an insecure one
refuses `tls/` endpoints it has no certificates for.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import zenoh

from coplane.bus.acl import access_control
from coplane.bus.codec import MAX_PAYLOAD_BYTES
from coplane.bus.security import (
    ROUTER,
    BusSecurity,
    current_security,
    server_of_identity,
    vehicle_of_identity,
)
from coplane.errors import ConfigError

# Zenoh's defragmentation bound (`transport/link/rx/max_message_size`, default 1 GiB): a larger
# fragmented message is dropped while it arrives instead of being buffered whole, by the router and
# by every session. Twice the wire limit, so nothing `decode` would accept is ever cut. Measured with
# Zenoh 1.10 (tests/bus/test_message_size.py): 8 and 20 MiB puts are dropped; the bound is not exact
# (some puts of a few MiB still arrive), so `decode` stays the 1 MiB check before parsing.
MAX_TRANSPORT_MESSAGE_BYTES = 2 * MAX_PAYLOAD_BYTES


def secure_endpoint(endpoint: str) -> str:
    """`tcp/host:port` -> `tls/host:port`; TLS endpoints unchanged."""
    if endpoint.startswith("tls/"):
        return endpoint
    if endpoint.startswith("tcp/"):
        return "tls/" + endpoint.removeprefix("tcp/")
    raise ConfigError(f"secure bus: endpoint {endpoint!r} must be tcp/... or tls/...")


def _endpoints(endpoints: Sequence[str], security: BusSecurity) -> list[str]:
    if security.secure:
        return [secure_endpoint(e) for e in endpoints]
    if any(e.startswith("tls/") for e in endpoints):
        raise ConfigError(
            "a tls/ endpoint needs certificates: set COPLANE_BUS_CERTS and COPLANE_BUS_IDENTITY"
        )
    return list(endpoints)


def tls_section(ca: Path | str, cert: Path | str, key: Path | str, side: str) -> dict[str, Any]:
    """`transport/link/tls` for `side` "listen" (the router) or "connect" (a client); mTLS both ways."""
    return {
        "root_ca_certificate": str(ca),
        f"{side}_certificate": str(cert),
        f"{side}_private_key": str(key),
        "enable_mtls": True,
        "verify_name_on_connect": True,
    }


def session_config(
    mode: str = "client",
    connect: Sequence[str] = (),
    listen: Sequence[str] = (),
    wait_for_router: bool = True,
    lease_ms: int | None = None,
    security: BusSecurity | None = None,
) -> zenoh.Config:
    """A Zenoh config with multicast scouting off (it does not cross Docker bridges anyway).

    `wait_for_router`: a client retries forever instead of failing at once when no router is up,
    so services can start in any order and survive router restarts. `lease_ms`: how fast a dead
    peer's liveliness tokens go away (docs/bus.md, Membership). `security`: default
    `current_security()` (the environment), see the module docstring.
    """
    sec = security if security is not None else current_security()
    c = zenoh.Config()
    c.insert_json5("mode", json.dumps(mode))
    c.insert_json5("scouting/multicast/enabled", "false")
    c.insert_json5("transport/link/rx/max_message_size", str(MAX_TRANSPORT_MESSAGE_BYTES))
    if connect:
        c.insert_json5("connect/endpoints", json.dumps(_endpoints(connect, sec)))
        if wait_for_router and mode != "router":
            c.insert_json5("connect/timeout_ms", "-1")
            c.insert_json5("connect/exit_on_failure", "false")
    if listen:
        c.insert_json5("listen/endpoints", json.dumps(_endpoints(listen, sec)))
    if lease_ms is not None:
        c.insert_json5("transport/link/tx/lease", str(lease_ms))
        c.insert_json5("transport/link/tx/keep_alive", "4")
    if sec.secure:
        side = "listen" if mode == "router" else "connect"
        c.insert_json5("transport/link/tls", json.dumps(tls_section(*sec.files(), side)))
    return c


def vehicles_in(certs: Path) -> list[str]:
    """The vehicles with a certificate in a certificates folder (what the router's ACL names)."""
    return sorted(v for p in certs.glob("vehicle-*.crt") if (v := vehicle_of_identity(p.stem)) is not None)


def servers_in(certs: Path) -> list[str]:
    """The fusion server ids with a certificate of their own in a certificates folder."""
    return sorted(s for p in certs.glob("fusion-*.crt") if (s := server_of_identity(p.stem)) is not None)


def router_config(
    listen: Sequence[str],
    security: BusSecurity | None = None,
    vehicles: Sequence[str] | None = None,
    fleet: str = "*",
    connect: Sequence[str] = (),
    servers: Sequence[str] | None = None,
) -> zenoh.Config:
    """A router listening on `listen` (what `python -m coplane.bus.router` opens).

    Secure: TLS listeners with the `router` certificate, client certificates required, and the
    access control of coplane.bus.acl for `vehicles` and the fusion servers' own identities
    `servers` (default: every vehicle and server certificate in the certificates folder) in `fleet`
    (default: any). `connect`: other routers to form a mesh with, retried until they are up, over
    mutual TLS with the same `router` certificate.
    """
    sec = security if security is not None else current_security()
    if sec.secure:
        sec = sec.as_identity(ROUTER)
    c = session_config("router", listen=listen, security=sec)
    if connect:
        c.insert_json5("connect/endpoints", json.dumps(_endpoints(connect, sec)))
        c.insert_json5("connect/timeout_ms", "-1")
        c.insert_json5("connect/exit_on_failure", "false")
        if sec.secure:
            both = {**tls_section(*sec.files(), "listen"), **tls_section(*sec.files(), "connect")}
            c.insert_json5("transport/link/tls", json.dumps(both))
    if sec.secure:
        assert sec.certs is not None
        names = list(vehicles) if vehicles is not None else vehicles_in(sec.certs)
        ids = list(servers) if servers is not None else servers_in(sec.certs)
        c.insert_json5("access_control", json.dumps(access_control(names, fleet, ids)))
    return c


def router_document(
    listen: Sequence[str],
    certs: str,
    vehicles: Sequence[str],
    fleet: str = "*",
    connect: Sequence[str] = (),
    servers: Sequence[str] = (),
) -> dict[str, Any]:
    """A zenohd configuration file's content (docker-compose's routers): the same TLS listener and
    access control as `router_config`, with the certificates at `certs` inside the container.
    `connect`: routers to form a mesh with, as `router_config` does (mutual TLS, retried forever).
    `servers`: the ids of fusion servers with identities of their own."""
    files = (f"{certs}/ca.crt", f"{certs}/{ROUTER}.crt", f"{certs}/{ROUTER}.key")
    tls = tls_section(*files, "listen")
    doc: dict[str, Any] = {
        "mode": "router",
        "listen": {"endpoints": [secure_endpoint(e) for e in listen]},
    }
    if connect:
        doc["connect"] = {
            "endpoints": [secure_endpoint(e) for e in connect],
            "timeout_ms": -1,
            "exit_on_failure": False,
        }
        tls = {**tls, **tls_section(*files, "connect")}
    doc |= {
        "scouting": {"multicast": {"enabled": False}},
        "transport": {"link": {"rx": {"max_message_size": MAX_TRANSPORT_MESSAGE_BYTES}, "tls": tls}},
        "access_control": access_control(vehicles, fleet, servers),
    }
    return doc
