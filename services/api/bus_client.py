"""The Zenoh side of the API: subscriptions to the fleet's solution, diagnostics and liveliness keys.

Zenoh callbacks run on Zenoh's threads and must return at once (a slow subscriber would back up
the router and, through BLOCK congestion control, the fusion server): they only copy the payload
and hand it to the event loop with `loop.call_soon_threadsafe`. Decoding and the state update run
on the loop, where the HTTP handlers read the state, so the state needs no locks. At most
`max_pending` payloads wait; beyond that new ones are dropped and counted.

The session is opened in a background thread because a client configured to wait for its router
(`connect/timeout_ms = -1`, see `coplane.bus.session_config`) blocks in `zenoh.open` until one is
up; the HTTP side (healthz, readyz = 503) is served meanwhile. Reconnection after a router restart
is Zenoh's own; liveliness tokens seen through the router go away with it and come back after.
"""

from __future__ import annotations

import asyncio
import logging
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any, Protocol

import zenoh

from coplane.bus import BadMessage, KeySpace, decode, payload_bytes, session_config
from coplane.messages import DiagnosticsMessage, SolutionMessage

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
        if n in (1, 10, 100, 1000) or n % 10_000 == 0:  # a flood of bad payloads must not flood logs
            log.warning("rejected bus payload", extra={"source": source, "reason": str(exc), "count": n})

    def solution(self, payload: bytes) -> None:
        try:
            sol = decode(SolutionMessage, payload)
        except BadMessage as exc:
            self._rejected("solution", exc)
            return
        now = self.clock()
        if self.state.on_solution(sol, now):
            ev = self.state.stream_event(sol, now)
            if ev is not None:
                self.hub.publish(ev)

    def diagnostics(self, payload: bytes) -> None:
        try:
            d = decode(DiagnosticsMessage, payload)
        except BadMessage as exc:
            self._rejected("diagnostics", exc)
            return
        self.state.on_diagnostics(d)

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
    """A Zenoh client session with the API's three subscriptions and its own liveliness token."""

    def __init__(self, fleet: str, connect: Sequence[str], lease_ms: int = 2000) -> None:
        self.keys = KeySpace(fleet)
        self.connect = list(connect)
        self.lease_ms = lease_ms
        self.session: Any = None
        self.token: Any = None
        self.ingest: Ingest | None = None
        self._closing = threading.Event()
        self._thread: threading.Thread | None = None
        self._checked = 0.0
        self._connected = False

    def start(self, ingest: Ingest) -> None:
        self.ingest = ingest
        self._thread = threading.Thread(target=self._open, name="zenoh-open", daemon=True)
        self._thread.start()

    def _open(self) -> None:
        assert self.ingest is not None
        ing = self.ingest
        while not self._closing.is_set():
            try:
                session = zenoh.open(session_config("client", self.connect, lease_ms=self.lease_ms))
                break
            except Exception as exc:  # a bad endpoint, say: keep serving HTTP, retry
                log.error("cannot open the Zenoh session", extra={"error": str(exc)[:300]})
                self._closing.wait(2.0)
        else:
            return
        if self._closing.is_set():
            session.close()
            return

        def on_solution(sample: Any) -> None:
            ing.submit(ing.solution, payload_bytes(sample))

        def on_diagnostics(sample: Any) -> None:
            ing.submit(ing.diagnostics, payload_bytes(sample))

        def on_alive(sample: Any) -> None:
            ing.submit(ing.alive, str(sample.key_expr), sample.kind == zenoh.SampleKind.PUT)

        session.declare_subscriber(self.keys.solution, on_solution)
        session.declare_subscriber(self.keys.diagnostics, on_diagnostics)
        session.liveliness().declare_subscriber(self.keys.all_alive("*"), on_alive, history=True)
        self.token = session.liveliness().declare_token(self.keys.alive("api", str(session.zid())[:32]))
        self.session = session
        log.info("bus session open", extra={"fleet": self.keys.fleet, "connect": ",".join(self.connect)})

    def connected(self) -> bool:
        """A router is connected right now (checked at most every 0.25 s)."""
        now = time.monotonic()
        if now - self._checked > 0.25:
            self._checked = now
            s = self.session
            try:
                self._connected = s is not None and not s.is_closed() and len(list(s.info.routers_zid())) > 0
            except Exception:
                self._connected = False
        return self._connected

    def close(self) -> None:
        self._closing.set()
        s, self.session = self.session, None
        if s is not None:
            try:
                if self.token is not None:
                    self.token.undeclare()
                s.close()
            except Exception:
                log.exception("closing the Zenoh session failed")
