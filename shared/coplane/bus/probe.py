"""Probe a live secure router: try every (identity x key x operation) and report what got through.

`probe_access` opens one session per identity (certificates from a `coplane certs init` folder),
tries every put, liveliness token and subscription that matters on one fleet's keys, and the road
map's area queries (answering one on a server's tiles key, asking one), and records for each
whether a legitimate listener (or the prober itself, for subscriptions and questions) received it,
beside
what the policy says (`allowed`, written from docs/bus.md's table, independently of the router's
ACL generator in coplane.bus.acl, so a wrong rule shows up as a mismatch). `probe_connections`
checks that clients without an acceptable certificate cannot connect at all.

tests/bus/test_access_control.py asserts the result; bench/reliability_security.py tabulates it.
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import zenoh

from coplane.bus.config import session_config
from coplane.bus.keys import KeySpace
from coplane.bus.security import API, FUSION, MONITOR, BusSecurity, server_of_identity, vehicle_of_identity

SETTLE_S = 0.6  # how long a denied message gets to show up anyway (a delivered one takes ms)


@dataclass(frozen=True)
class Attempt:
    """One try: `identity` did `operation` on `key` (relative to the fleet prefix)."""

    identity: str
    key: str
    operation: str  # put | token | subscribe | liveliness-subscribe | answer | ask | connect
    allowed: bool  # what the policy says
    delivered: bool  # what happened through the router


def allowed(identity: str, key: str, operation: str, vehicles: Sequence[str]) -> bool:
    """The policy, key relative to `coplane/v1/<fleet>/` (docs/bus.md, Security); a vehicle
    certificate counts only for the fleet's `vehicles`. `fusion` speaks for any server,
    `fusion-<id>` only for server <id> (its solution, diagnostics, tiles and token keys); both hear
    what a fusion server hears."""
    vid = vehicle_of_identity(identity)
    if vid is not None and vid not in vehicles:
        return False
    sid = server_of_identity(identity)
    server = identity == FUSION or sid is not None
    parts = key.split("/")
    regional = len(parts) == 7 and parts[0] == "shard" and parts[2] == "region" and parts[4] == "vehicle"
    tiles = parts[:2] == ["map", "tiles"] and len(parts) <= 3
    # regions: one key per server, the server's id its last chunk
    per_server = (len(parts) == 2 and parts[0] in ("solution", "diagnostics")) or (tiles and len(parts) == 3)
    if operation == "put":
        if vid is not None:
            return parts[:2] == ["vehicle", vid] or (regional and parts[5] == vid)
        if sid is not None:
            return per_server and parts[-1] == sid
        return identity == FUSION and (key in ("solution", "diagnostics") or tiles or per_server)
    if operation == "token":
        if parts[0] != "alive" or len(parts) != 3:
            return False
        role, ident = parts[1], parts[2]
        return (
            (vid is not None and role == "agent" and ident == vid)
            or (identity == FUSION and role == "fusion")
            or (sid is not None and role == "fusion" and ident == sid)
            or (identity == API and role == "api")
        )
    if operation == "subscribe":
        if key.startswith("vehicle/") or regional:
            return server
        if tiles:  # the servers' tiles stream, for (regions) the other servers; agents ask instead
            return server
        if parts[0] == "solution":  # the fusion servers hear each other's (hand-over seeds)
            return vid is not None or server or identity in (API, MONITOR)
        return parts[0] == "diagnostics" and identity in (API, MONITOR)
    if operation == "answer":  # a queryable for the agents' area queries: a server's own tiles key
        return tiles and ((identity == FUSION) or (sid is not None and per_server and parts[-1] == sid))
    if operation == "ask":  # an area query for the tiles: the fleet's vehicles
        return tiles and vid is not None
    if operation == "liveliness-subscribe":  # agents' and servers' tokens, as fusion servers follow them
        if key == "alive/fusion/*":  # the servers' tokens: every consumer of solutions follows them
            return vid is not None or server or identity in (API, MONITOR)
        return (server and key == "alive/agent/*") or identity in (API, MONITOR)
    return False


class _Seen:
    """Payloads and tokens seen by the listeners (Zenoh threads append, the prober reads)."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.items: set[tuple[str, str]] = set()

    def add(self, key: str, what: str) -> None:
        with self.lock:
            self.items.add((key, what))

    def has(self, key: str, what: str) -> bool:
        with self.lock:
            return (key, what) in self.items

    def wait(self, key: str, what: str, timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.has(key, what):
                return True
            time.sleep(0.01)
        return self.has(key, what)


def _open(endpoint: str, security: BusSecurity, wait: bool = False) -> zenoh.Session:
    return zenoh.open(session_config("client", [endpoint], wait_for_router=wait, security=security))


def client_config(endpoint: str, security: BusSecurity) -> zenoh.Config:
    """A client that tries `endpoint` once (no waiting for the router)."""
    return session_config("client", [endpoint], wait_for_router=False, security=security)


def anonymous_tls_config(endpoint: str, ca: Path) -> zenoh.Config:
    """A TLS client that trusts the router's CA but presents no certificate of its own."""
    c = session_config("client", security=BusSecurity(insecure=True))
    c.insert_json5("connect/endpoints", json.dumps([endpoint]))
    c.insert_json5("transport/link/tls/root_ca_certificate", json.dumps(str(ca)))
    return c


def probe_connections(candidates: dict[str, zenoh.Config]) -> list[Attempt]:
    """Each candidate config tries to connect; `delivered` is whether it got a session with the
    router (for a forbidden candidate, any session at all is a failure)."""
    out = []
    for name, cfg in candidates.items():
        try:
            s = zenoh.open(cfg)
        except Exception:
            connected = False
        else:
            connected = bool(list(s.info.routers_zid()))
            s.close()
        out.append(Attempt(name, "-", "connect", False, connected))
    return out


def probe_access(
    endpoint: str,
    certs: Path,
    fleet: str,
    identities: Sequence[str],
    vehicles: Sequence[str],
    progress: Callable[[Attempt], None] | None = None,
) -> list[Attempt]:
    """Try every identity x key x operation through the router at `endpoint` (see module doc)."""
    k = KeySpace(fleet)
    base = BusSecurity(certs=certs)
    sessions: dict[str, zenoh.Session] = {}
    keep: list[Any] = []  # subscribers and tokens live as long as the probe
    seen = _Seen()
    out: list[Attempt] = []

    def rel(key: str) -> str:
        return key.removeprefix(k.prefix + "/")

    def session(identity: str) -> zenoh.Session:
        if identity not in sessions:
            sessions[identity] = _open(endpoint, base.as_identity(identity), wait=True)
        return sessions[identity]

    def record(a: Attempt) -> None:
        out.append(a)
        if progress is not None:
            progress(a)

    # legitimate listeners: the fusion server (nodes, agent tokens) and the API (the rest)
    listeners = {who: _open(endpoint, base.as_identity(who), wait=True) for who in (FUSION, API)}
    try:
        on_put = lambda s: seen.add(str(s.key_expr), s.payload.to_bytes().decode())  # noqa: E731
        on_token = lambda s: seen.add(str(s.key_expr), str(s.kind))  # noqa: E731
        keep.append(listeners[FUSION].declare_subscriber(k.all_nodes, on_put))
        keep.append(listeners[FUSION].declare_subscriber(k.all_region_nodes, on_put))
        keep.append(listeners[FUSION].liveliness().declare_subscriber(k.all_alive("agent"), on_token))
        keep.append(listeners[API].declare_subscriber(k.all_solutions, on_put))
        keep.append(listeners[API].declare_subscriber(f"{k.diagnostics}/**", on_put))
        keep.append(listeners[API].liveliness().declare_subscriber(f"{k.prefix}/alive/*/*", on_token))
        # the map tiles' legitimate listener is another server (agents ask by area instead)
        tile_listener = _open(endpoint, base.as_identity(FUSION), wait=True)
        listeners["tiles"] = tile_listener
        keep.append(tile_listener.declare_subscriber(k.all_map_tiles, on_put))
        for identity in identities:
            session(identity)
        time.sleep(0.5)  # every session knows the listeners (a client puts only where one listens)
        data_keys = [
            *(k.node(v) for v in vehicles),
            *_region_keys(k, vehicles),
            k.solution,
            k.diagnostics,
            k.map_tiles,
        ]
        # -- puts: all at once, each payload names its sender, then one settle
        for identity in identities:
            for key in data_keys:
                session(identity).put(key, f"{identity}|{key}")
        time.sleep(SETTLE_S)
        for identity in identities:
            for key in data_keys:
                ok = allowed(identity, rel(key), "put", vehicles)
                got = seen.wait(key, f"{identity}|{key}", 2.0 if ok else 0.0)
                record(Attempt(identity, rel(key), "put", ok, got))
        # -- liveliness tokens (a token carries no sender): per key, the forbidden ones together,
        # one at a time only if something got through; the allowed ones one at a time
        token_keys = [
            *(k.alive("agent", v) for v in vehicles),
            k.alive("fusion", "0"),
            k.alive("fusion", "s1"),
            k.alive("api", "x"),
        ]
        for key in token_keys:
            denied = [i for i in identities if not allowed(i, rel(key), "token", vehicles)]
            if denied and _try_tokens(key, [session(i) for i in denied], seen, SETTLE_S):
                for i in denied:
                    record(
                        Attempt(i, rel(key), "token", False, _try_tokens(key, [session(i)], seen, SETTLE_S))
                    )
            else:
                for i in denied:
                    record(Attempt(i, rel(key), "token", False, False))
            for i in identities:
                if i not in denied:
                    record(Attempt(i, rel(key), "token", True, _try_tokens(key, [session(i)], seen, 3.0)))
        # -- subscriptions: each identity listens, the legitimate publisher puts
        out.extend(_probe_subscriptions(k, identities, vehicles, base, endpoint, session, rel, progress))
        # -- area queries: each identity answers (a vehicle asks) and asks (a server answers)
        for a in _probe_queries(k, identities, vehicles, base, endpoint, session, rel):
            record(a)
    finally:
        for s in [*sessions.values(), *listeners.values()]:
            s.close()
    return out


def _region_keys(k: KeySpace, vehicles: Sequence[str]) -> list[str]:
    """The keys of a fleet with regions (docs/scale.md): a vehicle's node under a shard and region,
    and server s1's solution, diagnostics and tiles."""
    own = k.server_keys("s1")
    return [k.region_node(3, "r1c2", v) for v in vehicles] + [own.solution, own.diagnostics, own.tiles]


def _probe_queries(
    k: KeySpace,
    identities: Sequence[str],
    vehicles: Sequence[str],
    base: BusSecurity,
    endpoint: str,
    session: Callable[[str], zenoh.Session],
    rel: Callable[[str], str],
) -> list[Attempt]:
    """The road map's area queries: every identity declares a queryable on the single server's and
    server s1's tiles keys, answering with its name, and a fleet vehicle asks `map/tiles/**`;
    then a fusion server answers "legit" and every identity asks."""
    out: list[Attempt] = []
    keys = [k.map_tiles, k.server_tiles("s1")]

    def ask(s: zenoh.Session) -> set[tuple[str, str]]:
        got = [
            (str(r.ok.key_expr), r.ok.payload.to_bytes().decode())
            for r in s.get(
                f"{k.all_map_tiles}?box=0,0,0,0",
                target=zenoh.QueryTarget.ALL,
                consolidation=zenoh.ConsolidationMode.NONE,  # every answer, several on one key
                timeout=2.0,
            )
            if r.ok is not None
        ]
        return set(got)

    def answering(s: zenoh.Session, key: str, name: str) -> Any:
        return s.declare_queryable(key, lambda q: q.reply(key, name))

    queryables = [answering(session(i), key, i) for i in identities for key in keys]
    asker = _open(endpoint, base.as_identity(f"vehicle-{vehicles[0]}"), wait=True)
    try:
        time.sleep(0.5)
        heard = ask(asker)
        for i in identities:
            for key in keys:
                out.append(
                    Attempt(
                        i, rel(key), "answer", allowed(i, rel(key), "answer", vehicles), (key, i) in heard
                    )
                )
    finally:
        for q in queryables:
            q.undeclare()
        asker.close()
    legit = _open(endpoint, base.as_identity(FUSION), wait=True)
    try:
        kept = answering(legit, k.map_tiles, "legit")
        time.sleep(0.5)
        for i in identities:
            got = (k.map_tiles, "legit") in ask(session(i))
            out.append(
                Attempt(i, rel(k.all_map_tiles), "ask", allowed(i, rel(k.map_tiles), "ask", vehicles), got)
            )
        kept.undeclare()
    finally:
        legit.close()
    return out


def _try_tokens(key: str, sessions: Sequence[zenoh.Session], seen: _Seen, timeout: float) -> bool:
    """Declare `key` from every session, wait for a listener to see it, withdraw: seen or not."""
    put, delete = (key, str(zenoh.SampleKind.PUT)), (key, str(zenoh.SampleKind.DELETE))
    tokens = [s.liveliness().declare_token(key) for s in sessions]
    got = seen.wait(*put, timeout)
    for t in tokens:
        t.undeclare()
    if got:  # wait for it to go, so the next try starts clean
        seen.wait(*delete, 3.0)
    with seen.lock:
        seen.items -= {put, delete}
    return got


def _probe_subscriptions(
    k: KeySpace,
    identities: Iterable[str],
    vehicles: Sequence[str],
    base: BusSecurity,
    endpoint: str,
    session: Callable[[str], zenoh.Session],
    rel: Callable[[str], str],
    progress: Callable[[Attempt], None] | None,
) -> list[Attempt]:
    seen = _Seen()
    subs: list[Any] = []
    publishers = {k.node(v): f"vehicle-{v}" for v in vehicles} | {
        k.region_node(3, "r1c2", vehicles[0]): f"vehicle-{vehicles[0]}",
        k.server_solution("s1"): FUSION,
        f"{k.diagnostics}/s1": FUSION,
        k.solution: FUSION,
        k.diagnostics: FUSION,
        k.map_tiles: FUSION,
        k.server_tiles("s1"): FUSION,
    }
    identities = list(identities)

    def on_sample(identity: str) -> Callable[[zenoh.Sample], None]:
        return lambda s: seen.add(str(s.key_expr), f"{identity}<{s.payload.to_bytes().decode()}")

    def on_token(identity: str) -> Callable[[zenoh.Sample], None]:
        return lambda s: seen.add(str(s.key_expr), f"{identity}<{s.kind}")

    for identity in identities:
        for key in publishers:
            subs.append(session(identity).declare_subscriber(key, on_sample(identity)))
        for role in ("agent", "fusion"):
            subs.append(
                session(identity).liveliness().declare_subscriber(k.all_alive(role), on_token(identity))
            )
    pubs = {key: _open(endpoint, base.as_identity(who), wait=True) for key, who in publishers.items()}
    time.sleep(0.5)
    try:
        for key, s in pubs.items():
            s.put(key, "legit")
        # the legitimate tokens: an agent's, and a server's (from the fusion identity's session)
        token_keys = {"agent": k.alive("agent", vehicles[0]), "fusion": k.alive("fusion", "0")}
        tokens = [
            pubs[k.node(vehicles[0])].liveliness().declare_token(token_keys["agent"]),
            pubs[k.solution].liveliness().declare_token(token_keys["fusion"]),
        ]
        time.sleep(SETTLE_S)
        out = []
        for identity in identities:
            for key in publishers:
                ok = allowed(identity, rel(key), "subscribe", vehicles)
                got = seen.wait(key, f"{identity}<legit", 2.0 if ok else 0.0)
                out.append(Attempt(identity, rel(key), "subscribe", ok, got))
            for role, token_key in token_keys.items():
                ok = allowed(identity, rel(k.all_alive(role)), "liveliness-subscribe", vehicles)
                got = seen.wait(token_key, f"{identity}<{zenoh.SampleKind.PUT}", 2.0 if ok else 0.0)
                out.append(Attempt(identity, rel(k.all_alive(role)), "liveliness-subscribe", ok, got))
        for token in tokens:
            token.undeclare()
        if progress is not None:
            for a in out:
                progress(a)
        return out
    finally:
        for s in pubs.values():
            s.close()
