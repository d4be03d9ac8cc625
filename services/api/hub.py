"""Fan-out of solution events to /stream clients: bounded per client, never blocks the producer.

Each client gets its own small queue; when a slow client's queue is full its oldest event is
dropped (counted), so one stalled browser cannot grow memory or hold up the bus side. Events are
serialised once per solution, not once per client.
"""

from __future__ import annotations

import asyncio

from .models import StreamEvent

Item = tuple[int, str] | None  # (seq, JSON of the StreamEvent); None ends the stream


class StreamHub:
    def __init__(self, max_clients: int = 32, queue_size: int = 64) -> None:
        self.max_clients = max_clients
        self.queue_size = queue_size
        self.clients: set[asyncio.Queue[Item]] = set()
        self.last: tuple[int, str] | None = None  # sent first to a new client
        self.published = 0
        self.dropped = 0
        self.closed = False

    @property
    def full(self) -> bool:
        return self.closed or len(self.clients) >= self.max_clients

    def subscribe(self) -> asyncio.Queue[Item]:
        q: asyncio.Queue[Item] = asyncio.Queue(self.queue_size)
        if self.last is not None:
            q.put_nowait(self.last)
        if self.closed:
            self._put(q, None)
        self.clients.add(q)
        return q

    def unsubscribe(self, q: asyncio.Queue[Item]) -> None:
        self.clients.discard(q)

    @staticmethod
    def _put(q: asyncio.Queue[Item], item: Item) -> bool:
        """Put, dropping the oldest item of a full queue; True if something was dropped."""
        dropped = False
        if q.full():
            q.get_nowait()
            dropped = True
        q.put_nowait(item)
        return dropped

    def publish(self, ev: StreamEvent) -> None:
        """Call on the event loop thread."""
        item = (ev.seq, ev.model_dump_json())
        self.last = item
        self.published += 1
        for q in self.clients:
            self.dropped += self._put(q, item)

    def close(self) -> None:
        """End every stream (server shutdown), so uvicorn is not kept waiting by open streams."""
        self.closed = True
        for q in self.clients:
            self._put(q, None)
