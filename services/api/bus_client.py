"""The Zenoh side of the API: subscriptions to the fleet's solution, diagnostics and liveliness keys.

The API's `BusNode` hands every event to the event loop with `loop.call_soon_threadsafe` (Zenoh's
threads must return at once: a slow subscriber would back up the router and, through BLOCK
congestion control, the fusion server). Decoding and the state update run on the loop, where the
HTTP handlers read the state, so the state needs no locks. At most `max_pending` events wait;
beyond that new ones are dropped and counted.

The node is opened in a background thread because a client configured to wait for its router
(`connect/timeout_ms = -1`, see `coplane.bus.session_config`) blocks until one is up; the HTTP
side (healthz, readyz = 503) is served meanwhile. Reconnection after a router restart is Zenoh's
own; liveliness tokens seen through the router go away with it and come back after.
"""

from __future__ import annotations

import asyncio
import logging
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any, Protocol

from coplane.bus import (
    BadMessage,
    BusEvent,
    BusNode,
    KeySpace,
    Payload,
    Presence,
    Subscription,
    decode,
    session_config,
)
from coplane.messages import DiagnosticsMessage, SolutionMessage
from coplane.runtime import RateLimitedLog

from .hub import StreamHub
from .state import FleetState

log = logging.getLogger("coplane.api")


class Ingest:
    """Bus payloads -> validated messages -> FleetState and the /stream hub (on the event loop)."""

    def __init__(
        self,
        state: FleetState,
        hub: StreamHub,
        max_pending: int = 10_000,
        clock: Callable[[], float] = time.time,
    ) -> None:
        self.state = state
        self.hub = hub
        self.max_pending = max_pending
        self.clock = clock
        self.loop: asyncio.AbstractEventLoop | None = None
        self.pending = 0
        self.dropped = 0
        self._lock = threading.Lock()
        self.warn = RateLimitedLog(log)  # a flood of bad or forged payloads must not flood the log

    def bind(self, loop: asyncio.AbstractEventLoop) -> None:
        self.loop = loop

    # -- any thread ---------------------------------------------------------------------------
    def submit(self, fn: Callable[..., None], *args: Any) -> None:
        """Schedule `fn(*args)` on the loop unless too much is already waiting (then drop it)."""
        loop = self.loop
        with self._lock:
            if loop is None or self.pending >= self.max_pending:
                self.dropped += 1
                return
            self.pending += 1
        try:
            loop.call_soon_threadsafe(self._run, fn, args)
        except RuntimeError:  # the loop is closed: we are shutting down
            with self._lock:
                self.pending -= 1

    def _run(self, fn: Callable[..., None], args: tuple[Any, ...]) -> None:
        with self._lock:
            self.pending -= 1
        try:
            fn(*args)
        except Exception:  # nothing from the bus may take the API down
            log.exception("bus message handling failed")

    # -- event loop thread --------------------------------------------------------------------
    def _rejected(self, source: str, exc: BadMessage) -> None:
        self.state.reject(source, exc.kind)
        n = self.state.rejected[source, exc.kind]
        self.warn.log(
            logging.WARNING,
            (source, exc.kind),
            "rejected bus payload",
            {"source": source, "reason": str(exc), "count": n},
        )

    def solution(self, payload: bytes, server: str = "") -> None:
        try:
            sol = decode(SolutionMessage, payload)
        except BadMessage as exc:
            self._rejected("solution", exc)
            return
        now = self.clock()
        if self.state.on_solution(sol, now, server):
            ev = self.state.stream_event(sol, now)
            if ev is not None:
                self.hub.publish(ev)
            return
        v = self.state.last_verdict
        if v is not None and v.reason is not None and v.reason != "repeat":
            n = self.state.rejected["solution", v.reason]
            self.warn.log(
                logging.WARNING,
                ("untrusted", v.reason),
                "untrusted solution ignored",
                {"reason": v.reason, "seq": sol.seq, "generation": sol.generation, "count": n},
            )

    def diagnostics(self, payload: bytes, server: str = "") -> None:
        try:
            d = decode(DiagnosticsMessage, payload)
        except BadMessage as exc:
            self._rejected("diagnostics", exc)
            return
        self.state.on_diagnostics(d, server)

    def alive(self, key: str, present: bool) -> None:
        ident = KeySpace.id_of_alive_key(key)
        if ident is None:
            self.state.reject("liveliness", "bad-key")
            return
        self.state.on_alive(ident[0], ident[1], present)


class Bus(Protocol):
    """What the app needs from its bus (tests inject an in-process one)."""

    def start(self, ingest: Ingest) -> None: ...

    def connected(self) -> bool: ...

    def close(self) -> None: ...


class LocalBus:
    """No network: tests and demos feed `ingest` themselves; `connected` is a plain flag."""

    def __init__(self, connected: bool = True) -> None:
        self.is_connected = connected
        self.ingest: Ingest | None = None
        self.closed = False

    def start(self, ingest: Ingest) -> None:
        self.ingest = ingest
        self.closed = False

    def connected(self) -> bool:
        return self.is_connected

    def close(self) -> None:
        self.closed = True


class ZenohBus:
    """A `BusNode` with the API's three subscriptions and its own liveliness token."""

    def __init__(self, fleet: str, connect: Sequence[str], lease_ms: int = 2000) -> None:
        self.keys = KeySpace(fleet)
        self.connect = list(connect)
        self.lease_ms = lease_ms
        self.node: BusNode | None = None
        self.ingest: Ingest | None = None
        self._closing = threading.Event()
        self._thread: threading.Thread | None = None
        self._checked = 0.0
        self._connected = False

    def start(self, ingest: Ingest) -> None:
        self.ingest = ingest
        self._thread = threading.Thread(target=self._open, name="zenoh-open", daemon=True)
        self._thread.start()

    def _new_node(self, ingest: Ingest) -> BusNode:
        keys = self.keys
        return BusNode(
            session_config("client", self.connect, lease_ms=self.lease_ms),
            # the API may run several times: its token is named by its session id
            token=lambda zid: keys.alive("api", zid[:32]),
            subscribe=[
                Subscription(keys.all_solutions),  # one server's `solution`, or several servers' (regions)
                Subscription(f"{keys.diagnostics}/**"),
                Subscription(keys.all_alive("*"), liveliness=True),
            ],
            sink=lambda event: self._route(ingest, event),
        )

    def _route(self, ingest: Ingest, event: BusEvent) -> None:
        """One bus event (on a Zenoh thread) to its handler on the loop."""
        if isinstance(event, Presence):
            ingest.submit(ingest.alive, event.key, event.alive)
        elif isinstance(event, Payload) and event.key.startswith(self.keys.solution):
            ingest.submit(ingest.solution, event.data, KeySpace.server_of_solution_key(event.key))
        elif isinstance(event, Payload) and event.key.startswith(self.keys.diagnostics):
            server = event.key.removeprefix(self.keys.diagnostics).lstrip("/")
            ingest.submit(ingest.diagnostics, event.data, server)

    def _open(self) -> None:
        assert self.ingest is not None
        while not self._closing.is_set():
            try:
                node = self._new_node(self.ingest).open()
                break
            except Exception as exc:  # a bad endpoint, say: keep serving HTTP, retry
                log.error("cannot open the Zenoh session", extra={"error": str(exc)[:300]})
                self._closing.wait(2.0)
        else:
            return
        if self._closing.is_set():
            node.close()
            return
        self.node = node
        log.info("bus session open", extra={"fleet": self.keys.fleet, "connect": ",".join(self.connect)})

    def connected(self) -> bool:
        """A router is connected right now (checked at most every 0.25 s)."""
        now = time.monotonic()
        if now - self._checked > 0.25:
            self._checked = now
            node = self.node
            self._connected = node is not None and node.routers_connected()
        return self._connected

    def close(self) -> None:
        self._closing.set()
        node, self.node = self.node, None
        if node is not None:
            try:
                node.close()
            except Exception:
                log.exception("closing the Zenoh session failed")
