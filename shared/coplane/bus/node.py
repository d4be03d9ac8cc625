"""`BusNode`: one process's place on the bus, opened and closed as a context manager.

    with BusNode(session_config("client", connect), token=keys.alive("agent", vid),
                 publish=[Publication(keys.node(vid), must_deliver=True)],
                 subscribe=[Subscription(keys.solution)]) as node:
        node.put(keys.node(vid), payload)
        event = node.get(timeout=0.05)   # a Payload, a Presence, a Request, an Answered, or None

Every service declares its session, publishers, subscriptions and liveliness token here, so QoS
and the thread hand-over are written once. Zenoh runs subscriber callbacks on its own threads and
they must return at once (a slow subscriber backs up the router and, through BLOCK congestion
control, the publisher): the node's callbacks only copy the payload into a typed event and hand it
over, in arrival order, to one FIFO queue (read with `get`/`drain`) or to a `sink` the owner gives
(the API hands events to its event loop). Decoding happens on the owner's side.

Queries go the same way: a query to one of the node's queryables (`serve`) is handed over as a
`Request`, which the owner answers from its own thread (`answer`); the replies to the node's own
`request` arrive as `Payload`s, followed by one `Answered` once every queryable has answered or
the timeout passed, so the owner sees a whole answer in order with everything else.
"""

from __future__ import annotations

import logging
import queue
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from types import TracebackType
from typing import Any

import zenoh
import zenoh.ext as zx

from coplane.bus.codec import payload_bytes

log = logging.getLogger("coplane.bus")


@dataclass(frozen=True)
class Publication:
    """A key this node puts on. `must_deliver`: reliable with congestion BLOCK (node messages,
    solutions); otherwise Zenoh's defaults, where the latest value wins (diagnostics).
    `history`: keep the last N samples in a cache (a Zenoh advanced publisher) that a subscriber
    with `history=True` receives when it starts late, e.g. a restarted fusion server."""

    key: str
    must_deliver: bool = False
    history: int = 0


@dataclass(frozen=True)
class Subscription:
    """A key expression this node listens to. `liveliness`: follow the liveliness tokens under it
    instead of samples, starting with the tokens already alive (history). `history`: first
    receive what the matching publishers with a cache still hold, also from publishers that
    appear later (a Zenoh advanced subscriber); plain publishers are heard as usual."""

    key: str
    liveliness: bool = False
    history: bool = False


@dataclass(frozen=True)
class Payload:
    """A sample put on a subscribed key: its concrete key and the raw, not yet validated, bytes."""

    key: str
    data: bytes


@dataclass(frozen=True)
class Presence:
    """A liveliness token appeared (`alive`) or went away (process ended, or its lease expired)."""

    key: str
    alive: bool


@dataclass(frozen=True)
class Request:
    """A query to one of this node's queryables: the key expression asked for, its selector
    parameters (not yet validated) and the Zenoh query to answer with `BusNode.answer`."""

    key: str
    parameters: dict[str, str]
    query: Any


@dataclass(frozen=True)
class Answered:
    """A `BusNode.request` finished: every reply to it came before this event. `tag` is the
    request's."""

    key: str
    tag: int


BusEvent = Payload | Presence | Request | Answered
Sink = Callable[[BusEvent], None]
TokenKey = str | Callable[[str], str]


class BusNode:
    """A Zenoh session with its publishers, subscriptions and liveliness token.

    `token`: the liveliness key to declare, or a function of the session id (for a process that
    may run more than once, such as the API). It is declared after the publishers and
    subscriptions, so a node that says it is alive can already hear and speak. `sink`: where events
    go instead of the node's own queue; it runs on a Zenoh thread and must not block.
    `history_later`: publications with a cache will be added while open (`add_publication`), so
    the session needs timestamps from the start. `serve`: key expressions to declare queryables
    on; their queries are handed over as `Request` events.
    """

    def __init__(
        self,
        config: zenoh.Config,
        *,
        token: TokenKey | None = None,
        publish: Iterable[Publication] = (),
        subscribe: Iterable[Subscription] = (),
        sink: Sink | None = None,
        history_later: bool = False,
        serve: Iterable[str] = (),
    ) -> None:
        self._config = config
        self._token_key = token
        self._publish = list(publish)
        self._subscribe = list(subscribe)
        self._sink = sink
        self._history_later = history_later  # publications with a cache may be added while open
        self._events: queue.Queue[BusEvent] = queue.Queue()
        self._session: zenoh.Session | None = None
        self._token: Any = None
        self._publishers: dict[str, Any] = {}
        self._subscribers: dict[str, Any] = {}
        self._serve = list(serve)  # keys of the queryables: their queries become `Request`s
        self._queryables: list[Any] = []

    # -- lifetime ------------------------------------------------------------------------------
    def open(self) -> BusNode:
        """Open the session and declare everything (blocks until a router is up if the config
        says to wait for one)."""
        if self._history_later or any(p.history for p in self._publish):
            # a publication cache needs timestamped samples (shared/notes.md, "Late joiners")
            self._config.insert_json5("timestamping/enabled", "true")
        session = zenoh.open(self._config)
        self._session = session
        try:
            self._declare(session)
        except BaseException:
            self.close()
            raise
        return self

    def _declare(self, session: zenoh.Session) -> None:
        for p in self._publish:
            self._publishers[p.key] = self._declare_publisher(session, p)
        for s in self._subscribe:
            self._subscribers[s.key] = self._declare_subscriber(session, s)
        for key in self._serve:
            self._queryables.append(session.declare_queryable(key, self._on_query))
        if self._token_key is not None:
            key = self._token_key if isinstance(self._token_key, str) else self._token_key(self.zid)
            self._token = session.liveliness().declare_token(key)

    @staticmethod
    def _declare_publisher(session: zenoh.Session, p: Publication) -> Any:
        qos: dict[str, Any] = {}
        if p.must_deliver:
            qos = {
                "congestion_control": zenoh.CongestionControl.BLOCK,
                "reliability": zenoh.Reliability.RELIABLE,
            }
        if p.history:
            return zx.declare_advanced_publisher(
                session,
                p.key,
                cache=zx.CacheConfig(max_samples=p.history),
                publisher_detection=True,  # so history subscribers find it when it starts late
                **qos,
            )
        return session.declare_publisher(p.key, **qos)

    def _declare_subscriber(self, session: zenoh.Session, s: Subscription) -> Any:
        if s.liveliness:
            return session.liveliness().declare_subscriber(s.key, self._on_presence, history=True)
        if s.history:
            return zx.declare_advanced_subscriber(
                session,
                s.key,
                self._on_sample,
                history=zx.HistoryConfig(detect_late_publishers=True),
            )
        return session.declare_subscriber(s.key, self._on_sample)

    # -- changing what it speaks and hears while open (regions: docs/scale.md) -----------------
    def add_publication(self, p: Publication) -> None:
        """Declare one more publisher (no-op if its key is declared); e.g. an agent entering a region."""
        if p.key not in self._publishers:
            self._publishers[p.key] = self._declare_publisher(self.session, p)

    def remove_publication(self, key: str) -> None:
        """Undeclare a publisher added before (no-op if there is none)."""
        pub = self._publishers.pop(key, None)
        if pub is not None:
            pub.undeclare()

    def subscribe(self, s: Subscription) -> None:
        """Declare one more subscription (no-op if its key is subscribed); e.g. a server taking
        over a shard. A history subscription first receives what the publishers' caches hold."""
        if s.key not in self._subscribers:
            self._subscribers[s.key] = self._declare_subscriber(self.session, s)

    def unsubscribe(self, key: str) -> None:
        """Undeclare a subscription (no-op if there is none); events already queued stay queued."""
        sub = self._subscribers.pop(key, None)
        if sub is not None:
            sub.undeclare()

    @property
    def subscriptions(self) -> list[str]:
        """The key expressions subscribed now."""
        return sorted(self._subscribers)

    @property
    def present(self) -> bool:
        """This node's liveliness token is declared."""
        return self._token is not None

    def set_present(self, present: bool) -> None:
        """Withdraw or re-declare the liveliness token while the session stays open: a vehicle
        whose receiver went silent is offline for the fleet (the server stops waiting for it) and
        comes back with its next epoch."""
        if self._session is None or self._token_key is None or present == self.present:
            return
        if present:
            key = self._token_key if isinstance(self._token_key, str) else self._token_key(self.zid)
            self._token = self._session.liveliness().declare_token(key)
        else:
            token, self._token = self._token, None
            token.undeclare()

    def close(self) -> None:
        """Withdraw the token (peers see this node go at once, not after the lease) and close."""
        session, self._session = self._session, None
        if session is None:
            return
        try:
            if self._token is not None:
                self._token.undeclare()
        finally:
            self._token = None
            self._publishers.clear()
            self._subscribers.clear()
            self._queryables.clear()
            session.close()

    def __enter__(self) -> BusNode:
        return self.open()

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    # -- using it ------------------------------------------------------------------------------
    @property
    def session(self) -> zenoh.Session:
        if self._session is None:
            raise RuntimeError("the bus node is not open")
        return self._session

    @property
    def zid(self) -> str:
        return str(self.session.zid())

    def put(self, key: str, payload: bytes) -> None:
        """Put on one of the declared publications."""
        self._publishers[key].put(payload)

    def request(self, selector: str, tag: int = 0, timeout_s: float = 5.0) -> None:
        """Query every matching queryable without waiting: the replies arrive as `Payload`s (the
        key each replier gave), then one `Answered(tag)`. Every reply is kept (no consolidation:
        an answer may be several messages on one key), and every queryable is asked."""
        key = selector.split("?", 1)[0]
        self.session.get(
            selector,
            zenoh.handlers.Callback(self._on_reply, lambda: self._deliver(Answered(key, tag))),
            target=zenoh.QueryTarget.ALL,
            consolidation=zenoh.ConsolidationMode.NONE,
            timeout=timeout_s,
        )

    @staticmethod
    def answer(request: Request, key: str, payloads: Iterable[bytes] = (), error: str | None = None) -> None:
        """Reply to a `Request` on `key` (one reply per payload, or an error reply) and finish it:
        the asker's `Answered` comes once every queryable asked has finished."""
        try:
            if error is not None:
                request.query.reply_err(error.encode())
            for data in payloads:
                request.query.reply(key, data)
        finally:
            request.query.drop()

    def get(self, timeout: float | None = None) -> BusEvent | None:
        """The next event in arrival order, or None if none came within `timeout` seconds."""
        try:
            return self._events.get(timeout=timeout)
        except queue.Empty:
            return None

    def poll(self) -> BusEvent | None:
        """The next event if one is waiting, else None (never blocks)."""
        try:
            return self._events.get_nowait()
        except queue.Empty:
            return None

    def drain(self) -> list[BusEvent]:
        """Every event waiting now, in arrival order."""
        out: list[BusEvent] = []
        while (ev := self.poll()) is not None:
            out.append(ev)
        return out

    def routers_connected(self) -> bool:
        """Whether a router is connected right now."""
        s = self._session
        try:
            return s is not None and not s.is_closed() and len(list(s.info.routers_zid())) > 0
        except Exception:
            return False

    # -- Zenoh threads -------------------------------------------------------------------------
    def _on_sample(self, sample: Any) -> None:
        self._deliver(Payload(str(sample.key_expr), payload_bytes(sample)))

    def _on_reply(self, reply: Any) -> None:
        if reply.ok is not None:  # an error reply is the answerer's word on a bad query: logged there
            self._on_sample(reply.ok)

    def _on_query(self, query: Any) -> None:
        self._deliver(Request(str(query.key_expr), dict(query.parameters), query))

    def _on_presence(self, sample: Any) -> None:
        self._deliver(Presence(str(sample.key_expr), sample.kind == zenoh.SampleKind.PUT))

    def _deliver(self, event: BusEvent) -> None:
        if self._sink is None:
            self._events.put(event)
            return
        try:
            self._sink(event)
        except Exception:  # never raise into Zenoh's thread
            log.exception("bus event sink failed", extra={"key": event.key[:120]})
