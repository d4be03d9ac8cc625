"""`GateSet`: one `SolutionGate` per fusion server, for a fleet spread over several servers by
region (docs/scale.md), with the rule that holds each server to its regions. Apart from
`trust.py`, which holds the rules every solution stream is gated by, one stream at a time."""

from __future__ import annotations

import dataclasses
import math
import time
from collections import Counter
from collections.abc import Callable, Iterable

from coplane.bus.keys import KeySpace
from coplane.bus.trust import SolutionGate, Verdict
from coplane.gtime import GpsTime
from coplane.messages import SolutionMessage
from coplane.regions import MOVE_GRACE_S, RegionConfig, may_speak_of, owned_shards

MAX_SERVERS = 256  # servers a consumer follows at once (bounded memory against invented keys)


class GateSet:
    """One `SolutionGate` per server key, for a fleet spread over several servers (regions,
    docs/scale.md): each server is its own generation and its own sequence of epochs, so each is
    gated on its own. The single server's `solution` key is the server "". At most `MAX_SERVERS`
    are followed; solutions on further keys are rejected as `too-many-servers`.

    `regions`: the fleet's region grid, for a consumer of a fleet with regions. A server's key is
    tied to its identity, but what it says of vehicles is not: a vehicle state on a server's key
    at a place none of that server's regions reaches (`regions.may_speak_of`) is dropped
    (`vehicle-not-owner`), the rest of the solution kept. Within `MOVE_GRACE_S` of a change of
    the live servers (and before any is known) every server may speak of every vehicle, since the
    processes' views of who owns what may differ. `exempt`: vehicles the consumer checks more
    closely itself (an agent its own, by the region it sent from: `RegionKeys.may_answer`)."""

    def __init__(
        self,
        fleet: str,
        regions: RegionConfig | None = None,
        exempt: Iterable[str] = (),
        clock: Callable[[], float] = time.monotonic,
        **options: object,
    ) -> None:
        self.fleet = fleet
        self.options = options
        self.gates: dict[str, SolutionGate] = {}
        self.overflow: Counter[str] = Counter()
        self.last_reason: str | None = None
        self.servers_alive: set[str] = set()  # fusion servers whose liveliness token is up
        self.regions, self.exempt, self.clock = regions, frozenset(exempt), clock
        self.servers_changed = -math.inf  # when `servers_alive` last changed (`regions`)
        self._owned: dict[str, tuple[frozenset[str], set[int]]] = {}  # server -> (live, its shards)

    def server_token(self, server_id: str, alive: bool) -> None:
        """A fusion server's liveliness token (`alive/fusion/<server_id>`) appeared or went away.
        Going away ends the run of that server's gate (regions: its own solution key), and of the
        single server's gate ("") once no fusion token is left: its solutions do not name their
        server, and a fleet with one server has one token. At most `MAX_SERVERS` tokens are
        remembered; beyond that (invented ones on an insecure bus) no gate ends early, and the
        quiet time decides as before."""
        if not server_id:
            return
        if alive:
            if len(self.servers_alive) < MAX_SERVERS and server_id not in self.servers_alive:
                self.servers_alive.add(server_id)
                self.servers_changed = self.clock()
            return
        if server_id in self.servers_alive:
            self.servers_alive.discard(server_id)
            self.servers_changed = self.clock()
        if (g := self.gates.get(server_id)) is not None:
            g.server_gone()
        if not self.servers_alive and (g := self.gates.get("")) is not None:
            g.server_gone()

    def settled(self) -> bool:
        """Whether the live servers are known and have not changed for `MOVE_GRACE_S`: only then
        do all processes agree on who owns which region, and a server is held to its own."""
        return bool(self.servers_alive) and self.clock() - self.servers_changed >= MOVE_GRACE_S

    def presence(self, key: str, alive: bool) -> bool:
        """A liveliness event from the bus: a fusion server's token goes to `server_token`;
        whether it was one (other roles' tokens and other keys are not this gate set's)."""
        ident = KeySpace.id_of_alive_key(key)
        if ident is None or ident[0] != "fusion":
            return False
        self.server_token(ident[1], alive)
        return True

    def on_token(self, key: str, alive: bool, now: float) -> SolutionMessage | None:
        """`presence`, and when a fusion server's token went away, the held first solution of its
        successor that this releases (`release`), for the consumer to take as if it came now."""
        if self.presence(key, alive) and not alive:
            return self.release(now)
        return None

    def gate(self, server: str) -> SolutionGate | None:
        g = self.gates.get(server)
        if g is None and len(self.gates) < MAX_SERVERS:
            g = self.gates[server] = SolutionGate(self.fleet, **self.options)  # type: ignore[arg-type]
        return g

    def check(self, server: str, sol: SolutionMessage, now: float, expect: GpsTime | None = None) -> Verdict:
        """`SolutionGate.check` by the gate of `server` (the key's server chunk)."""
        g = self.gate(server)
        if g is None:
            self.overflow["too-many-servers"] += 1
            self.last_reason = "too-many-servers"
            return Verdict(None, "too-many-servers")
        v = g.check(sol, now, expect)
        self.last_reason = g.last_reason
        return self._owned_only(server, v)

    def _owned_only(self, server: str, v: Verdict) -> Verdict:
        """`v` without the states of vehicles `server` may not speak of (see the class)."""
        sol = v.solution
        if sol is None or self.regions is None or not server or not self.settled():
            return v
        live = frozenset(self.servers_alive)
        if (cached := self._owned.get(server)) is None or cached[0] != live:
            mine = owned_shards(server, live, self.regions.shards) if server in live else set()
            cached = self._owned[server] = (live, mine)  # a server not alive owns nothing
        shards, cfg = cached[1], self.regions
        ok = [
            vs.vehicle_id in self.exempt or may_speak_of(vs.position_ecef_m, shards, cfg)
            for vs in sol.vehicles
        ]
        if all(ok):
            return v
        kept = [vs for vs, k in zip(sol.vehicles, ok, strict=True) if k]
        dropped = tuple(
            (vs.vehicle_id, "vehicle-not-owner") for vs, k in zip(sol.vehicles, ok, strict=True) if not k
        )
        self.overflow["vehicle-not-owner"] += len(dropped)
        return dataclasses.replace(
            v, solution=sol.model_copy(update={"vehicles": kept}), dropped=v.dropped + dropped
        )

    def release(self, now: float) -> SolutionMessage | None:
        """A held new-generation message that may now be taken (see `SolutionGate.release`), held
        to its server's regions as `check` holds the others."""
        for server, g in self.gates.items():
            if g.held is not None and (v := g.release(now)) is not None:
                return self._owned_only(server, v).solution
        return None

    @property
    def counts(self) -> Counter[str]:
        """Every gate's rejections, added up."""
        out: Counter[str] = Counter(self.overflow)
        for g in self.gates.values():
            out.update(g.counts)
        return out
