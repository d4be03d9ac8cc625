"""What a live byte source reports: connection state, reconnects, bytes and the age of its data.

Shared by every transport (file, TCP, serial, NTRIP), so the agent, its metrics and the API read
one shape whatever the source.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Protocol


@dataclass
class SourceStatus:
    """Mutable status of one source; written by its reader thread, read by anyone."""

    name: str
    connected: bool = False
    connects: int = 0  # successful (re)connections
    failures: int = 0  # failed connection attempts and dropped connections
    bytes: int = 0
    last_data_monotonic: float | None = None
    last_error: str | None = None
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False, compare=False)

    def data(self, n: int) -> None:
        """`n` bytes arrived now."""
        with self._lock:
            self.bytes += n
            self.last_data_monotonic = time.monotonic()

    def up(self) -> None:
        with self._lock:
            self.connected = True
            self.connects += 1
            self.last_error = None

    def down(self, error: str | None) -> None:
        with self._lock:
            self.connected = False
            self.failures += 1
            self.last_error = error

    def age_s(self) -> float | None:
        """Seconds since the last byte (None before the first)."""
        t = self.last_data_monotonic
        return None if t is None else time.monotonic() - t

    def snapshot(self) -> dict[str, object]:
        """A JSON-able copy for logs, metrics and the API."""
        with self._lock:
            age = self.age_s()
            return {
                "name": self.name,
                "connected": self.connected,
                "connects": self.connects,
                "failures": self.failures,
                "bytes": self.bytes,
                "age_s": None if age is None else round(age, 3),
                "last_error": self.last_error,
            }


class ByteSource(Protocol):
    """A transport that yields raw bytes until `stop` is set, reconnecting with backoff on its own.

    `chunks` never raises on I/O errors (they are recorded in `status` and retried); it returns
    when `stop` is set or, for a finite source such as a file, at its end.
    """

    status: SourceStatus

    def chunks(self, stop: threading.Event) -> Iterator[bytes]: ...


@dataclass
class Backoff:
    """Exponential reconnect delay: `first`, doubling up to `cap`, reset after a good connection."""

    first_s: float = 0.5
    cap_s: float = 5.0  # a receiver back from an outage is read again within this
    _next: float = 0.0

    def __post_init__(self) -> None:
        self._next = self.first_s

    def reset(self) -> None:
        self._next = self.first_s

    def wait(self, stop: threading.Event) -> bool:
        """Sleep the current delay (True if `stop` was set meanwhile) and double it."""
        delay, self._next = self._next, min(self.cap_s, self._next * 2.0)
        return stop.wait(delay)
