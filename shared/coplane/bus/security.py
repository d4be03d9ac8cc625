"""Bus security settings: which certificates a process uses and who it is (docs/bus.md, Security).

A process becomes secure without a code change: `session_config` and the router read
`BusSecurity` from the environment (`COPLANE_BUS_CERTS`, `COPLANE_BUS_IDENTITY`,
`COPLANE_BUS_INSECURE`) or the `[bus]` table of the `COPLANE_CONFIG` TOML file, so the fleet
launcher and docker-compose only set three variables per process. A process that talks to the bus
as more than one identity (the `coplane fleet` launcher's own listener) uses `use_security`.

Identities are certificate common names: `router`, `fusion`, `api`, `monitor` (read-only
listeners such as `coplane fleet`'s collector) and `vehicle-<id>` per vehicle; the prefix keeps a
vehicle called "fusion" from ever being the fusion server. Fusion servers that share a fleet by
region (docs/scale.md) each have their own, `fusion-<server id>`: the router's ACL then lets a
server put only its own solution, diagnostics and tile keys and declare only its own liveliness
token, so one server's certificate cannot speak for another. `fusion` is the identity of a fleet's
one server, and a server of any id may still use it (one certificate for every server: each may
then speak for the others, the deployment's choice).
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Iterator
from pathlib import Path

from pydantic_settings import SettingsConfigDict

from coplane.errors import ConfigError
from coplane.ids import is_vehicle_id
from coplane.runtime import ServiceSettings

log = logging.getLogger("coplane.bus")

ROUTER = "router"
FUSION = "fusion"
API = "api"
MONITOR = "monitor"
SERVICE_IDENTITIES = (ROUTER, FUSION, API, MONITOR)
VEHICLE_PREFIX = "vehicle-"
SERVER_PREFIX = FUSION + "-"
INSECURE_WARNING = "INSECURE BUS: plain TCP, no authentication, no access control; anyone who reaches the router can forge any message"


def _prefixed(prefix: str, ident: str, what: str) -> str:
    """`prefix` + a valid id (a key chunk: the identity's keys name it), else a ConfigError."""
    if not is_vehicle_id(ident):
        raise ConfigError(f"invalid {what} id {ident!r} (expected [A-Za-z0-9_-]{{1,32}})")
    return prefix + ident


def _id_after(prefix: str, identity: str) -> str | None:
    ident = identity.removeprefix(prefix)
    return ident if identity.startswith(prefix) and is_vehicle_id(ident) else None


def vehicle_identity(vehicle_id: str) -> str:
    """The certificate common name of a vehicle."""
    return _prefixed(VEHICLE_PREFIX, vehicle_id, "vehicle")


def vehicle_of_identity(identity: str) -> str | None:
    """The vehicle id of a `vehicle-<id>` identity, else None."""
    return _id_after(VEHICLE_PREFIX, identity)


def server_identity(server_id: str) -> str:
    """The certificate common name of one fusion server of a fleet with regions."""
    return _prefixed(SERVER_PREFIX, server_id, "server")


def server_of_identity(identity: str) -> str | None:
    """The server id of a `fusion-<id>` identity, else None (also for the shared `fusion`)."""
    return _id_after(SERVER_PREFIX, identity)


def check_identity(identity: str) -> str:
    """`identity` if it is one the bus knows (a service, a vehicle's, a server's own), else a ConfigError."""
    if identity in SERVICE_IDENTITIES or vehicle_of_identity(identity) or server_of_identity(identity):
        return identity
    raise ConfigError(
        f"unknown bus identity {identity!r}: expected one of {', '.join(SERVICE_IDENTITIES)}, "
        "fusion-<server id> or vehicle-<id>"
    )


class BusSecurity(ServiceSettings):
    """How this process joins the bus. Secure (mTLS, and ACL at the router) when `certs` is set and
    `insecure` is not; plain TCP otherwise."""

    model_config = SettingsConfigDict(env_prefix="COPLANE_BUS_", extra="ignore")
    toml_table: str = "bus"
    certs: Path | None = None  # folder made by `coplane certs init`
    identity: str | None = None  # this process's certificate (its common name)
    insecure: bool = False  # force plain TCP even if certs is set (debugging only)

    @property
    def secure(self) -> bool:
        return self.certs is not None and not self.insecure

    def files(self) -> tuple[Path, Path, Path]:
        """(CA certificate, this identity's certificate, its key), checked to exist."""
        if self.certs is None or not self.identity:
            raise ConfigError("secure bus: COPLANE_BUS_CERTS and COPLANE_BUS_IDENTITY must both be set")
        check_identity(self.identity)
        out = (
            self.certs / "ca.crt",
            self.certs / f"{self.identity}.crt",
            self.certs / f"{self.identity}.key",
        )
        for p in out:
            if not p.is_file():
                raise ConfigError(f"secure bus: {p} not found (run `coplane certs init {self.certs}`)")
        return out

    def env(self) -> dict[str, str]:
        """The environment that gives a child process these settings."""
        if not self.secure:
            return {"COPLANE_BUS_INSECURE": "1"}
        assert self.certs is not None
        return {
            "COPLANE_BUS_CERTS": str(self.certs),
            "COPLANE_BUS_IDENTITY": self.identity or "",
            "COPLANE_BUS_INSECURE": "0",
        }

    def as_identity(self, identity: str) -> BusSecurity:
        return self.model_copy(update={"identity": check_identity(identity)})


def check_server_identity(security: BusSecurity, server_id: str | None) -> None:
    """Refuse to start a fusion server whose bus identity cannot speak for it, which the router
    would silently drop every put of: `fusion` serves any server, `fusion-<id>` only server <id> of
    a fleet with regions (`server_id`; None: the fleet's one server, whose keys name none). An
    insecure bus has no identities to check."""
    identity = security.identity
    if not security.secure or identity == FUSION:
        return
    own = server_of_identity(identity or "")
    if own is None:
        raise ConfigError(
            f"a fusion server needs the bus identity {FUSION} or {SERVER_PREFIX}<id>, got {identity!r}"
        )
    if server_id is None:
        raise ConfigError(
            f"bus identity {identity!r} belongs to server {own} of a fleet with regions: "
            f"run with --regions true --server_id {own}, or as identity {FUSION}"
        )
    if own != server_id:
        raise ConfigError(
            f"bus identity {identity!r} belongs to server {own}, not to --server_id {server_id}"
        )


_global: list[BusSecurity] = []


def current_security() -> BusSecurity:
    """The settings `session_config` uses when not given any: the innermost `use_security`, else
    the environment / TOML."""
    if _global:
        return _global[-1]
    return BusSecurity()


@contextlib.contextmanager
def use_security(security: BusSecurity) -> Iterator[BusSecurity]:
    """Within the block, sessions opened by this process (any thread) use `security`."""
    _global.append(security)
    try:
        yield security
    finally:
        _global.remove(security)


def warn_insecure(where: str) -> None:
    log.warning(INSECURE_WARNING, extra={"where": where})
