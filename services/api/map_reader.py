"""The road map file as the API reads it: one cached read-only connection, reopened when the file is
replaced, and the request counts of the map endpoints for /metrics.

Why cached: opening a map file runs SQLite's `quick_check` over the whole file (RoadMapDb checks
what it opens), which costs time in proportion to the map, on every request if it were opened per
request. Why that is safe: the file is in WAL mode, so an idle read-only connection blocks no
writer (the fusion server, `coplane map build`), and every read sees the newest committed state.
A file replaced under the same name (a new inode: `mv`, a rebuilt map) is noticed by `stat` on the
next request and reopened; a file that disappears is "not there yet" again; any SQLite error while
reading drops the connection, so the next request opens (and checks) the file afresh.
"""

from __future__ import annotations

import contextlib
import os
import sqlite3
import threading
from collections import Counter
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TypeVar

from prometheus_client.core import CounterMetricFamily, Metric
from prometheus_client.registry import Collector

from coplane.errors import CoplaneError
from coplane.store.roadmap_db import RoadMapDb

T = TypeVar("T")


class MapError(Exception):
    """The map cannot answer: `status` 404 (none configured, not created yet) or 503 (unreadable)."""

    def __init__(self, status: int, detail: str) -> None:
        super().__init__(detail)
        self.status = status
        self.detail = detail


class MapReader(Collector):
    """Reads the map file for the map endpoints (from worker threads: one reader at a time)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._db: RoadMapDb | None = None
        self._ident: tuple[Path, int, int] | None = None  # (path, st_dev, st_ino) of the open file
        self.opens = 0
        self.requests: Counter[tuple[str, int]] = Counter()  # (path, status)

    def read(self, path: Path | None, fn: Callable[[RoadMapDb], T]) -> T:
        """`fn(db)` on the map at `path`; MapError 404 / 503 naming the file otherwise."""
        if path is None:
            raise MapError(
                404,
                "no road map configured (map = none): start the API with --map auto|FILE"
                " (environment COPLANE_API_MAP)",
            )
        with self._lock:
            try:
                st = os.stat(path)
            except FileNotFoundError:
                self._drop()
                raise MapError(
                    404,
                    f"road map {path} does not exist yet (the fusion server or `coplane map build` creates it)",
                ) from None
            except OSError as exc:
                self._drop()
                raise MapError(503, f"road map {path} unavailable: {exc.strerror or exc}") from None
            ident = (path, st.st_dev, st.st_ino)
            if self._db is None or self._ident != ident:
                self._drop()
                try:
                    self._db = RoadMapDb(path, readonly=True)
                except (CoplaneError, sqlite3.Error, OSError) as exc:
                    raise MapError(503, f"road map {path} unavailable: {exc}") from None
                self._ident = ident
                self.opens += 1
            try:
                return fn(self._db)
            except (CoplaneError, sqlite3.Error, OSError) as exc:
                self._drop()  # the next request opens and checks the file again
                raise MapError(503, f"road map {path} unavailable: {exc}") from None

    def _drop(self) -> None:
        if self._db is not None:
            with contextlib.suppress(sqlite3.Error):
                self._db.close()
        self._db = None
        self._ident = None

    def close(self) -> None:
        with self._lock:
            self._drop()

    def count(self, path: str, status: int) -> None:
        self.requests[(path, status)] += 1

    def collect(self) -> Iterator[Metric]:
        req = CounterMetricFamily(
            "coplane_api_map_requests",
            "Requests to the road-map endpoints, by path and HTTP status (404: no map, 422: bad"
            " parameters, 503: map file unreadable)",
            labels=["path", "status"],
        )
        for (p, status), n in sorted(self.requests.items()):
            req.add_metric([p, str(status)], float(n))
        yield req
        opens = CounterMetricFamily(
            "coplane_api_map_opens",
            "Times the API opened the road map file (first use, replaced, after an error)",
        )
        opens.add_metric([], float(self.opens))
        yield opens
