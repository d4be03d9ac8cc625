"""Agents' area queries, answered between the fusion server's solves (docs/roadmap.md, "Tiles on
the bus").

At a fleet's start every agent asks for its whole box at once: 200 agents' boxes are seconds of
the server's CPU, 1000 about 20 s (`bench/roadmap_fetch.py`). Answered as they arrived, they held
the server's loop that long, and no epoch was solved meanwhile. Here they wait in arrival order
and the loop answers them in slices of at most `slice_s` after it has solved the epochs that are
ready, so a map answer delays a solution by one slice and one answer at most.

A query that has waited longer than its asker waits (`max_wait_s`, below `MapFetch`'s 5 s) is
finished with an error instead of answered for nobody (`query-expired`); the agent asks again a
second later. At most `max_queued` queries wait; one more is refused at once (`query-overflow`).
Queries still waiting when the server stops are refused (`query-stopped`), so no asker waits for
its timeout. Zenoh's queryable has no queue of its own that a server could bound: a query's
callback has to be answered or dropped, hence this one.
"""

from __future__ import annotations

import time
from collections import Counter, deque
from collections.abc import Callable

from coplane.bus import Request

MAX_WAIT_S = 4.0  # an agent's request times out after 5 s (`MapFetch.timeout_s`)
MAX_QUEUED = 4096
SLICE_S = 0.05  # the longest run of answers between two looks at the epochs ready to solve

Answer = Callable[[Request, str], None]  # answer one query on a key
Refuse = Callable[[Request, str, str], None]  # finish one query on a key with an error


class QueryQueue:
    """Area queries waiting for an answer, oldest first, with the time each arrived."""

    def __init__(
        self,
        counts: Counter[str],
        max_wait_s: float = MAX_WAIT_S,
        max_queued: int = MAX_QUEUED,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.counts = counts
        self.max_wait_s, self.max_queued, self.clock = max_wait_s, max_queued, clock
        self._waiting: deque[tuple[float, Request, str]] = deque()
        self.longest_wait_s = 0.0  # of the queries answered, for the diagnostics

    def __len__(self) -> int:
        return len(self._waiting)

    def add(self, request: Request, key: str, refuse: Refuse) -> None:
        """Queue `request` (to be answered on `key`), or refuse it when `max_queued` wait."""
        if len(self._waiting) >= self.max_queued:
            self.counts["query-overflow"] += 1
            refuse(request, key, f"server busy: {len(self._waiting)} area queries waiting")
            return
        self._waiting.append((self.clock(), request, key))

    def serve(self, answer: Answer, refuse: Refuse, slice_s: float = SLICE_S) -> int:
        """Answer the oldest queries for about `slice_s` (at least one), refusing those that
        waited past `max_wait_s` on the way; how many were answered."""
        start = self.clock()
        answered = 0
        while self._waiting:
            now = self.clock()
            if answered and now - start >= slice_s:
                break
            arrived, request, key = self._waiting.popleft()
            if now - arrived > self.max_wait_s:
                self.counts["query-expired"] += 1
                refuse(request, key, f"area query expired: {now - arrived:.1f} s in the server's queue")
                continue
            self.longest_wait_s = max(self.longest_wait_s, now - arrived)
            answer(request, key)
            answered += 1
        return answered

    def close(self, refuse: Refuse) -> int:
        """Refuse every query still waiting (the server stops); how many there were."""
        n = len(self._waiting)
        while self._waiting:
            _, request, key = self._waiting.popleft()
            refuse(request, key, "server stopping")
        self.counts["query-stopped"] += n
        return n
