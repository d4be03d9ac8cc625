"""Rate-limited logging: what untrusted senders cause must never flood a service's log.

A hostile or broken sender can make a service reject thousands of messages a second; logging each
would fill the disk and bury everything else. `RateLimitedLog` lets one record per key (e.g.
(vehicle, reason)) through every `every_s` seconds; the next one carries how many were suppressed
in between. Keys are bounded (`max_keys`, least recently logged dropped first) so hostile keys
cannot grow memory either. The counts themselves belong in metrics, not in the log.
"""

from __future__ import annotations

import logging
import time
from collections import OrderedDict
from collections.abc import Callable, Hashable
from typing import Any


class RateLimitedLog:
    """At most one record per key per `every_s`, with the number suppressed since the last one."""

    def __init__(
        self,
        logger: logging.Logger,
        every_s: float = 10.0,
        max_keys: int = 1024,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.logger = logger
        self.every_s = every_s
        self.max_keys = max_keys
        self.clock = clock
        self._last: OrderedDict[Hashable, tuple[float, int]] = OrderedDict()  # key -> (logged at, suppressed)
        self.suppressed = 0  # in total, for tests and metrics

    def log(self, level: int, key: Hashable, msg: str, extra: dict[str, Any] | None = None) -> bool:
        """Log `msg` unless this key was logged less than `every_s` ago; True if it was logged."""
        now = self.clock()
        last = self._last.get(key)
        if last is not None and now - last[0] < self.every_s:
            self._last[key] = (last[0], last[1] + 1)
            self.suppressed += 1
            return False
        fields = dict(extra or {})
        if last is not None and last[1]:
            fields["suppressed"] = last[1]
        self.logger.log(level, msg, extra=fields)
        self._last[key] = (now, 0)
        self._last.move_to_end(key)
        while len(self._last) > self.max_keys:
            self._last.popitem(last=False)
        return True

    def warning(self, key: Hashable, msg: str, extra: dict[str, Any] | None = None) -> bool:
        """`log` at WARNING."""
        return self.log(logging.WARNING, key, msg, extra)
