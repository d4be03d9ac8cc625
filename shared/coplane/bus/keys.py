"""The versioned Zenoh key space (docs/bus.md).

    coplane/v1/<fleet>/vehicle/<id>/node        NodeMessage, vehicle -> server
    coplane/v1/<fleet>/shard/<s>/region/<r>/vehicle/<id>/node
                                                the same, with regions (docs/scale.md)
    coplane/v1/<fleet>/shard/<s>/region/<r>/vehicle/<id>/near/<home>
                                                a copy for region <r> of a vehicle in region
                                                <home> near their boundary
    coplane/v1/<fleet>/solution                 SolutionMessage, server -> vehicles, API
    coplane/v1/<fleet>/solution/<server>        the same, from one of several servers (regions)
    coplane/v1/<fleet>/diagnostics              DiagnosticsMessage, server -> API
    coplane/v1/<fleet>/map/tiles                MapTilesMessage, the road map's tiles, server -> agents
    coplane/v1/<fleet>/map/tiles/<server>       the same, from one of several servers (regions)
    coplane/v1/<fleet>/alive/<role>/<id>        liveliness tokens (role: agent | fusion | api)

With regions, a vehicle publishes under the shard and region of its position (and a copy to each
region within `margin_m`), and each fusion server subscribes to the shards it owns
(`coplane.regions`).
Fleet and vehicle ids are their own chunks, so `coplane/v1/<fleet>/vehicle/*/node` selects all
vehicles and a router ACL can limit a vehicle to its own keys.
"""

from __future__ import annotations

from dataclasses import dataclass

KEY_ROOT = "coplane/v1"


@dataclass(frozen=True)
class ServerKeys:
    """The keys one fusion server puts on: the fleet's one server's plain keys, or with regions
    the keys that name it (which the router's ACL ties to its identity, coplane.bus.acl)."""

    solution: str
    diagnostics: str
    tiles: str


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

    def region_node(self, shard: int, region: str, vehicle_id: str) -> str:
        """A vehicle's node key when the fleet runs with regions."""
        return f"{self.prefix}/shard/{shard}/region/{region}/vehicle/{vehicle_id}/node"

    def region_copy(self, shard: int, region: str, vehicle_id: str, home: str) -> str:
        """The copy of a vehicle's node message for a region near its own (`home`)."""
        return f"{self.prefix}/shard/{shard}/region/{region}/vehicle/{vehicle_id}/near/{home}"

    def shard_nodes(self, shard: int) -> str:
        """Every node key and copy of one shard: what its owning server subscribes to."""
        return f"{self.prefix}/shard/{shard}/region/*/vehicle/*/**"

    @property
    def all_region_nodes(self) -> str:
        return f"{self.prefix}/shard/*/region/*/vehicle/*/**"

    @property
    def solution(self) -> str:
        return f"{self.prefix}/solution"

    def server_solution(self, server: str) -> str:
        """One server's solutions when several share the fleet (regions)."""
        return f"{self.prefix}/solution/{server}"

    @property
    def all_solutions(self) -> str:
        """The single server's `solution` key and every server's `solution/<server>` (`**` also
        matches no chunk at all)."""
        return f"{self.prefix}/solution/**"

    @property
    def diagnostics(self) -> str:
        return f"{self.prefix}/diagnostics"

    def server_keys(self, server: str | None) -> ServerKeys:
        """Server `server`'s keys with regions; None: the fleet's one server's."""
        if server is None:
            return ServerKeys(self.solution, self.diagnostics, self.map_tiles)
        return ServerKeys(
            self.server_solution(server), f"{self.diagnostics}/{server}", self.server_tiles(server)
        )

    @property
    def map_tiles(self) -> str:
        """The road map's tiles, from the fusion server (docs/roadmap.md, on the bus)."""
        return f"{self.prefix}/map/tiles"

    def server_tiles(self, server: str) -> str:
        """One server's tiles when several share the fleet (regions): the key names the writer,
        so the router's ACL can hold each server's identity to its own (coplane.bus.acl)."""
        return f"{self.prefix}/map/tiles/{server}"

    @property
    def all_map_tiles(self) -> str:
        """The single server's `map/tiles` and every server's `map/tiles/<server>`."""
        return f"{self.prefix}/map/tiles/**"

    def alive(self, role: str, ident: str) -> str:
        return f"{self.prefix}/alive/{role}/{ident}"

    def all_alive(self, role: str = "*") -> str:
        return f"{self.prefix}/alive/{role}/*"

    @staticmethod
    def vehicle_of_node_key(key: str) -> str | None:
        """The <id> chunk of a node key (either form), or None if the key is not a node key."""
        parts = key.split("/")
        if len(parts) == 6 and parts[3] == "vehicle" and parts[5] == "node":
            return parts[4]
        regional = len(parts) >= 10 and parts[3] == "shard" and parts[5] == "region" and parts[7] == "vehicle"
        if regional and (
            (len(parts) == 10 and parts[9] == "node") or (len(parts) == 11 and parts[9] == "near")
        ):
            return parts[8]
        return None

    @staticmethod
    def region_of_node_key(key: str) -> tuple[int, str, str] | None:
        """(shard, region it was put to, the vehicle's own region) of a regional node key or copy;
        None for a plain node key, or not a node key."""
        parts = key.split("/")
        if KeySpace.vehicle_of_node_key(key) is None or parts[3] != "shard" or not parts[4].isdigit():
            return None
        return int(parts[4]), parts[6], parts[10] if len(parts) == 11 else parts[6]

    @staticmethod
    def server_of_solution_key(key: str) -> str:
        """The <server> chunk of a solution key; "" for the single server's `solution`."""
        parts = key.split("/")
        return parts[4] if len(parts) == 5 and parts[3] == "solution" else ""

    @staticmethod
    def server_of_tiles_key(key: str) -> str | None:
        """The <server> chunk of a tiles key, "" for the single server's `map/tiles`; None for a
        key that is not a tiles key."""
        parts = key.split("/")
        if len(parts) < 5 or parts[3:5] != ["map", "tiles"]:
            return None
        return parts[5] if len(parts) == 6 else "" if len(parts) == 5 else None

    @staticmethod
    def id_of_alive_key(key: str) -> tuple[str, str] | None:
        """(role, id) of a liveliness key, or None if the key is not one."""
        parts = key.split("/")
        if len(parts) == 6 and parts[3] == "alive":
            return parts[4], parts[5]
        return None
