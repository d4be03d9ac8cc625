"""The router's access control: what each certificate common name may do, default deny.

Zenoh 1.10 checks every message crossing the router against rules of (message type, flow, key
expressions) granted to subjects (here: certificate common names, which mTLS makes trustworthy).
`ingress` is what a client sends to the router, `egress` what the router forwards to it; anything
not granted is dropped, in both directions. The grants, with P = `coplane/v1/<fleet>`:

| identity | sends (ingress) | receives (egress) |
| --- | --- | --- |
| `vehicle-<id>` | put `P/vehicle/<id>/**`; token `P/alive/agent/<id>`; subscribe `P/solution` and the servers' tokens `P/alive/fusion/*`; its node publisher's cache (queryable, replies, token under `P/vehicle/<id>/node/@adv/**`); area queries for the map tiles `P/map/tiles/**` | `P/solution`; the servers' tokens; queries for its own cache; subscriber declarations on node keys; the servers' answers with map tiles |
| `fusion` (a fleet's one server, or a certificate all servers share) | put `P/solution/**`, `P/diagnostics/**`, `P/map/tiles/**`; token `P/alive/fusion/*`; subscribe every node key, the agents' and servers' tokens and the other servers' solutions; history queries to the nodes' caches; the map publisher's cache (queryable, replies, token under `P/map/tiles/**/@adv/**`); the queryable and answers for the agents' area queries on `P/map/tiles/**`; the other servers' tiles, with history queries to their caches | every node put, cache reply and token; agent and server tokens; other servers' solutions; subscriber declarations on solution, diagnostics and map tiles; the agents' area queries and queries for the map cache; the other servers' tiles, their caches' replies and tokens |
| `fusion-<id>` (one server of a fleet with regions, `--server_id <id>`) | as `fusion`, but put only `P/solution/<id>`, `P/diagnostics/<id>` and `P/map/tiles/<id>`, token only `P/alive/fusion/<id>`, its map cache and area queryable only on `P/map/tiles/<id>` (and its `@adv/**`) | as `fusion` |
| `api` | subscribe `P/solution`, `P/diagnostics`, tokens under `P/alive`; token `P/alive/api/*` | those |
| `monitor` | subscribe `P/solution`, `P/diagnostics`, tokens under `P/alive` | those |
| `router` | everything under `P` (another router of the mesh, docs/scale.md) | everything under `P` |

A Zenoh client's publisher sends only while it knows of a matching subscriber, so the publishers
also receive the subscriber declarations on their keys (measured: without them a publisher declared
before its subscribers never delivers). A vehicle's node publisher keeps a history cache (a Zenoh advanced publisher): its queryable and
liveliness token live under the verbatim chunk `@adv`, which `**` never matches, so those keys are
granted explicitly. `<fleet>` is `*` unless a fleet is named: a certificate is a vehicle's
identity, not a fleet's. `delete`, `declare_queryable` elsewhere and `query` elsewhere are
granted to nobody: no vehicle can answer another's area query.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from coplane.bus.keys import KeySpace
from coplane.bus.security import API, FUSION, MONITOR, ROUTER, server_identity, vehicle_identity

Grant = tuple[str, tuple[str, ...], tuple[str, ...]]  # (flow, messages, key expressions)

SUBSCRIBE_LIVELINESS = ("declare_liveliness_subscriber", "liveliness_query")
ALL_MESSAGES = (
    "put", "delete", "declare_subscriber", "query", "declare_queryable", "reply", "liveliness_token",
    *SUBSCRIBE_LIVELINESS,
)  # fmt: skip


def grants(vehicles: Sequence[str], fleet: str = "*", servers: Sequence[str] = ()) -> dict[str, list[Grant]]:
    """Every identity's grants (see the module docstring); `servers`: the ids of the fusion
    servers with identities of their own (`fusion-<id>`)."""
    k = KeySpace(fleet)
    p = k.prefix
    # regions (docs/scale.md): node keys under shard/region, several servers' solution keys
    nodes_adv = f"{k.all_nodes}/@adv/**"
    rnodes, rnodes_adv = k.all_region_nodes, f"{k.all_region_nodes}/@adv/**"
    sols, diags = k.all_solutions, f"{k.diagnostics}/**"
    alive_all = f"{p}/alive/*/*"
    # the road map: the single server's `map/tiles` and each server's `map/tiles/<id>` (`**`
    # matches no chunk too), with their cached publishers' verbatim @adv chunks
    tiles, tiles_adv = k.all_map_tiles, f"{k.all_map_tiles}/@adv/**"
    # the road map: an agent asks the servers' queryables for the tiles around it, and only
    # they answer (docs/roadmap.md, "Tiles on the bus")
    tile_asker: list[Grant] = [("ingress", ("query",), (tiles,)), ("egress", ("reply",), (tiles,))]
    # ... the servers' tiles stream (a server's cached publisher, the other servers' subscribers)
    tile_reader: list[Grant] = [
        ("ingress", ("declare_subscriber",), (tiles, tiles_adv)),
        ("ingress", SUBSCRIBE_LIVELINESS, (tiles_adv,)),
        ("ingress", ("query",), (tiles_adv,)),
        ("egress", ("put",), (tiles,)),
        ("egress", ("reply",), (tiles, tiles_adv)),
        ("egress", ("liveliness_token",), (tiles_adv,)),
    ]
    out: dict[str, list[Grant]] = {}
    for v in vehicles:
        own = f"{p}/vehicle/{v}/**"
        adv = f"{k.node(v)}/@adv/**"
        r_own = f"{p}/shard/*/region/*/vehicle/{v}/**"
        r_adv = f"{p}/shard/*/region/*/vehicle/{v}/node/@adv/**"
        out[vehicle_identity(v)] = [
            ("ingress", ("put",), (own, r_own)),
            ("ingress", ("declare_subscriber",), (k.solution, sols)),
            # the servers' tokens: a restarted server's solutions are taken at once (bus.trust)
            ("ingress", SUBSCRIBE_LIVELINESS, (k.all_alive("fusion"),)),
            ("egress", ("liveliness_token",), (k.all_alive("fusion"),)),
            ("ingress", ("liveliness_token",), (k.alive("agent", v), adv, r_adv)),
            ("ingress", ("declare_queryable",), (adv, r_adv)),
            ("ingress", ("reply",), (own, adv, r_own, r_adv)),
            ("egress", ("put",), (k.solution, sols)),
            ("egress", ("query",), (adv, r_adv)),
            ("egress", ("declare_subscriber",), (k.all_nodes, nodes_adv, rnodes, rnodes_adv)),
            *tile_asker,
        ]
    # what every fusion server hears: the agents' nodes (and their caches), tokens, the other
    # servers' solutions (hand-over seeds) and, with regions, their tiles (docs/scale.md)
    server_hears: list[Grant] = [
        ("ingress", ("declare_subscriber",), (k.all_nodes, nodes_adv, rnodes, rnodes_adv, sols)),
        (
            "ingress",
            SUBSCRIBE_LIVELINESS,
            (k.all_alive("agent"), k.all_alive("fusion"), nodes_adv, rnodes_adv),
        ),
        ("ingress", ("query",), (nodes_adv, rnodes_adv)),
        ("egress", ("put",), (k.all_nodes, rnodes, sols)),
        ("egress", ("reply",), (k.all_nodes, nodes_adv, rnodes, rnodes_adv)),
        (
            "egress",
            ("liveliness_token",),
            (k.all_alive("agent"), k.all_alive("fusion"), nodes_adv, rnodes_adv),
        ),
        *tile_reader,
        # the subscriber declarations and history queries that reach its publishers: the
        # consumers declare wildcards (every server's solutions, tiles), which a grant on one
        # server's keys alone would not include, and its publishers would then never send
        ("egress", ("declare_subscriber",), (k.solution, k.diagnostics, sols, diags, tiles, tiles_adv)),
        ("egress", ("query",), (tiles, tiles_adv)),  # ... and the agents' area queries
    ]
    # the shared `fusion` identity speaks for any server; `fusion-<id>` only for its own
    out[FUSION] = [
        *server_hears,
        *_server_speaks((k.solution, k.diagnostics, sols, diags), k.all_alive("fusion"), tiles, tiles_adv),
    ]
    for sid in servers:
        keys = k.server_keys(sid)
        out[server_identity(sid)] = [
            *server_hears,
            *_server_speaks(
                (keys.solution, keys.diagnostics), k.alive("fusion", sid), keys.tiles, f"{keys.tiles}/@adv/**"
            ),
        ]
    readers = [
        ("ingress", ("declare_subscriber",), (k.solution, k.diagnostics, sols, diags)),
        ("ingress", SUBSCRIBE_LIVELINESS, (alive_all,)),
        ("egress", ("put",), (k.solution, k.diagnostics, sols, diags)),
        ("egress", ("liveliness_token",), (alive_all,)),
    ]
    out[API] = [*readers, ("ingress", ("liveliness_token",), (k.all_alive("api"),))]
    out[MONITOR] = list(readers)
    # another router of the mesh forwards every client's traffic, already checked by its own ACL
    # at the client's link: everything under P both ways, the caches' verbatim @adv chunks too
    mesh = (f"{p}/**", f"{p}/**/@adv/**")
    out[ROUTER] = [("ingress", ALL_MESSAGES, mesh), ("egress", ALL_MESSAGES, mesh)]
    return out


def _server_speaks(puts: tuple[str, ...], token: str, tiles: str, tiles_adv: str) -> list[Grant]:
    """What a fusion server sends: `puts` (solutions, diagnostics), its liveliness `token`, and
    its tiles with their cached publisher (queryable, replies, token under `tiles_adv`) and the
    queryable that answers the agents' area queries on `tiles`."""
    return [
        ("ingress", ("put",), (*puts, tiles)),
        ("ingress", ("liveliness_token",), (token, tiles_adv)),
        ("ingress", ("declare_queryable",), (tiles, tiles_adv)),
        ("ingress", ("reply",), (tiles, tiles_adv)),
    ]


def access_control(vehicles: Sequence[str], fleet: str = "*", servers: Sequence[str] = ()) -> dict[str, Any]:
    """The router's `access_control` section: default deny, one subject per identity."""
    rules: list[dict[str, Any]] = []
    subjects: list[dict[str, Any]] = []
    policies: list[dict[str, Any]] = []
    for identity, granted in grants(vehicles, fleet, servers).items():
        ids = []
        for i, (flow, messages, keys) in enumerate(granted):
            rid = f"{identity}-{i}"
            ids.append(rid)
            rules.append(
                {
                    "id": rid,
                    "messages": list(messages),
                    "flows": [flow],
                    "permission": "allow",
                    "key_exprs": list(keys),
                }
            )
        subjects.append({"id": identity, "cert_common_names": [identity]})
        policies.append({"id": identity, "rules": ids, "subjects": [identity]})
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    }
