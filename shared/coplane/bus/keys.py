"""The versioned Zenoh key space (docs/bus.md).

    coplane/v1/<fleet>/vehicle/<id>/node        NodeMessage, vehicle -> server
    coplane/v1/<fleet>/solution                 SolutionMessage, server -> vehicles, API
    coplane/v1/<fleet>/diagnostics              DiagnosticsMessage, server -> API
    coplane/v1/<fleet>/alive/<role>/<id>        liveliness tokens (role: agent | fusion | api)

Fleet and vehicle ids are their own chunks, so `coplane/v1/<fleet>/vehicle/*/node` selects all
vehicles and a router ACL can limit a vehicle to its own keys.
"""

from __future__ import annotations

from dataclasses import dataclass

KEY_ROOT = "coplane/v1"


@dataclass(frozen=True)
class KeySpace:
    """Every key of one fleet; the only place key strings are built or parsed."""

    fleet: str

    @property
    def prefix(self) -> str:
        return f"{KEY_ROOT}/{self.fleet}"

    def node(self, vehicle_id: str) -> str:
        return f"{self.prefix}/vehicle/{vehicle_id}/node"

    @property
    def all_nodes(self) -> str:
        return f"{self.prefix}/vehicle/*/node"

    @property
    def solution(self) -> str:
        return f"{self.prefix}/solution"

    @property
    def diagnostics(self) -> str:
        return f"{self.prefix}/diagnostics"

    @property
    def map_tiles(self) -> str:
        """The road map's tiles, from the fusion server (docs/roadmap.md, on the bus)."""
        return f"{self.prefix}/map/tiles"

    def alive(self, role: str, ident: str) -> str:
        return f"{self.prefix}/alive/{role}/{ident}"

    def all_alive(self, role: str = "*") -> str:
        return f"{self.prefix}/alive/{role}/*"

    @staticmethod
    def vehicle_of_node_key(key: str) -> str | None:
        """The <id> chunk of a node key, or None if the key is not a node key."""
        parts = key.split("/")
        if len(parts) == 6 and parts[3] == "vehicle" and parts[5] == "node":
            return parts[4]
        return None

    @staticmethod
    def id_of_alive_key(key: str) -> tuple[str, str] | None:
        """(role, id) of a liveliness key, or None if the key is not one."""
        parts = key.split("/")
        if len(parts) == 6 and parts[3] == "alive":
            return parts[4], parts[5]
        return None
