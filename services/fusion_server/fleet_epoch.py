"""The fleet's current epoch, kept incrementally: the active vehicles' latest epochs as counts.

Admission asks for the median of the active vehicles' latest epochs on every node message (is it
too far ahead?) and the pacing on every loop (is a pending epoch outside the window?). Rebuilding
that from every vehicle each time is O(N) per message, O(N^2) per epoch: at 1000 vehicles it was a
quarter of the server's CPU (docs/performance-scale.md). Here an update costs O(log N) and a
median O(K log K), K the distinct latest epochs (a handful: the fleet is within a few epochs of
itself). A vehicle stops being active `silent_after_s` after its last admitted message; the
expiries wait in a heap. `now` is the caller's monotonic clock; a query with an earlier `now`
than the last one (only tests do that) rebuilds, so the answers are always the exact ones.
The active vehicles' first epochs (where each began) are kept the same way, for the fleet's start.
"""

from __future__ import annotations

import heapq
import math
from collections import Counter

from coplane.gtime import GpsTime


class FleetEpochs:
    """Latest admitted epoch of every vehicle heard within `silent_after_s`."""

    def __init__(self, silent_after_s: float) -> None:
        self.silent_after_s = silent_after_s
        # vehicle -> (latest epoch, last admit, first epoch)
        self._heard: dict[str, tuple[GpsTime, float, GpsTime]] = {}
        self._active: dict[str, GpsTime] = {}
        self._counts: Counter[GpsTime] = Counter()  # latest epochs of the active vehicles
        self._first_counts: Counter[GpsTime] = Counter()  # their first epochs
        self._expiry: list[tuple[float, str]] = []  # (last admit, vehicle), stale entries skipped
        self._now = -math.inf

    def update(
        self, vid: str, latest: GpsTime | None, last_admit_s: float | None, first: GpsTime | None = None
    ) -> None:
        """The vehicle's admission state changed (None: it has none, e.g. it went offline);
        `first`: its earliest admitted epoch (`latest` if not given)."""
        self._deactivate(vid)
        if latest is None or last_admit_s is None:
            self._heard.pop(vid, None)
            return
        self._heard[vid] = (latest, last_admit_s, latest if first is None else first)
        self._activate(vid)  # the next query expires it if it is already silent
        heapq.heappush(self._expiry, (last_admit_s, vid))
        if len(self._expiry) > 4 * len(self._heard) + 64:  # stale entries: rebuild the heap
            self._expiry = [(h[1], v) for v, h in self._heard.items()]
            heapq.heapify(self._expiry)

    def active(self, now: float) -> dict[str, GpsTime]:
        """Latest epoch of each active vehicle (a copy)."""
        self._advance(now)
        return dict(self._active)

    def count(self, now: float) -> int:
        """How many vehicles are active."""
        self._advance(now)
        return len(self._active)

    def median(self, now: float, exclude: str | None = None, upper: bool = False) -> GpsTime | None:
        """Lower (or `upper`) median of the active vehicles' latest epochs, leaving `exclude` out;
        None when no other vehicle is active."""
        self._advance(now)
        skip = self._active.get(exclude) if exclude is not None else None
        return _median(self._counts, len(self._active), skip, upper)

    def first_median(self, now: float) -> GpsTime | None:
        """Lower median of the active vehicles' first epochs (where the fleet began); None when no
        vehicle is active."""
        self._advance(now)
        return _median(self._first_counts, len(self._active), None, False)

    # -- internals ---------------------------------------------------------------------------
    def _advance(self, now: float) -> None:
        if now < self._now:
            self._rebuild(now)
            return
        self._now = now
        heap = self._expiry
        while heap and now - heap[0][0] > self.silent_after_s:  # as Admission's rule, to the bit
            s, vid = heapq.heappop(heap)
            heard = self._heard.get(vid)
            if heard is not None and heard[1] == s:  # its newest entry: it went silent
                self._deactivate(vid)

    def _rebuild(self, now: float) -> None:
        self._now = now
        self._active.clear()
        self._counts.clear()
        self._first_counts.clear()
        for vid, (_, s, _) in self._heard.items():
            if now - s <= self.silent_after_s:
                self._activate(vid)
        self._expiry = [(h[1], v) for v, h in self._heard.items()]
        heapq.heapify(self._expiry)

    def _activate(self, vid: str) -> None:
        latest, _, first = self._heard[vid]
        self._active[vid] = latest
        self._counts[latest] += 1
        self._first_counts[first] += 1

    def _deactivate(self, vid: str) -> None:
        """Uncount an active vehicle; call it before `_heard[vid]` changes (its first epoch is
        read from there)."""
        t = self._active.pop(vid, None)
        if t is not None:
            _uncount(self._counts, t)
            _uncount(self._first_counts, self._heard[vid][2])


def _uncount(counts: Counter[GpsTime], t: GpsTime) -> None:
    counts[t] -= 1
    if counts[t] == 0:
        del counts[t]


def _median(counts: Counter[GpsTime], n: int, skip: GpsTime | None, upper: bool) -> GpsTime | None:
    """Lower (or `upper`) median of the `n` epochs counted in `counts`, one `skip` left out."""
    if skip is not None:
        n -= 1
    if n <= 0:
        return None
    k = n // 2 if upper else (n - 1) // 2  # index into the sorted epochs
    for t in sorted(counts):
        c = counts[t] - (1 if t == skip else 0)
        if k < c:
            return t
        k -= c
    raise AssertionError("counts out of step with the active vehicles")
