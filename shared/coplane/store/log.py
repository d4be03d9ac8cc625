"""`SolutionLog`: an append-only SQLite log of fleet solutions, committed before `append` returns.

Why SQLite: it is in the standard library, one file per log, and a transaction either is in the
file or is not, so a `kill -9` at any instant leaves every returned `append` readable and never a
torn row (docs/reliability/durability.md measures the cost). The log runs in WAL mode, so other
processes can read it while its one writer appends; `synchronous` chooses what a commit survives:
FULL (the default) fsyncs the WAL on every commit and survives a power loss, NORMAL survives a
crash of the process but not of the machine.

Each row keeps the solution's wire JSON exactly as the bus carries it, plus indexed columns
(fleet, method, server generation if the message has one, seq, epoch week/tow, when it was
appended). A small key-value `meta` table holds the writer's state (open or cleanly closed) and
whatever the owner wants to resume (the fusion server's counters). The file is marked with an
application id and a schema version (`PRAGMA user_version`): a foreign or corrupt file, or a newer
schema, is a `StoreError` naming the file, never a silent overwrite.
"""

from __future__ import annotations

import fcntl
import json
import os
import sqlite3
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from coplane.errors import CoplaneError
from coplane.messages import SolutionMessage

APPLICATION_ID = 0x63706C6E  # "cpln": marks a file as a coplane log
SCHEMA_VERSION = 1
Synchronous = Literal["NORMAL", "FULL"]

_SCHEMA = """
CREATE TABLE solutions (
    id INTEGER PRIMARY KEY,
    fleet TEXT NOT NULL,
    method TEXT NOT NULL,
    generation TEXT,
    seq INTEGER NOT NULL,
    week INTEGER NOT NULL,
    tow REAL NOT NULL,
    appended_unix_s REAL NOT NULL,
    body TEXT NOT NULL
);
CREATE INDEX solutions_by_run ON solutions (fleet, method, id);
CREATE TABLE solution_vehicles (
    vehicle_id TEXT NOT NULL,
    solution_id INTEGER NOT NULL REFERENCES solutions (id),
    PRIMARY KEY (vehicle_id, solution_id)
) WITHOUT ROWID;
CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
"""


class StoreError(CoplaneError):
    """A log file that cannot be used: not a coplane log, corrupt, a newer schema, or locked."""


@dataclass(frozen=True)
class StoredSolution:
    """One row of the log: its id (append order), when it was appended, and the solution."""

    id: int
    appended_unix_s: float
    solution: SolutionMessage


def _generation(sol: SolutionMessage) -> str | None:
    g = getattr(sol, "generation", None)  # the server generation, once the wire model carries one
    return None if g is None else str(g)


class SolutionLog:
    """One SQLite file. `writer=True` takes the single-writer lock and creates the file if needed;
    readers (`writer=False`) may be other processes and never change the file."""

    def __init__(self, path: Path | str, *, writer: bool = True, synchronous: Synchronous = "FULL") -> None:
        self.path = Path(path)
        self.writer = writer
        self._lock_fd: int | None = None
        if writer:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._lock_fd = self._take_lock()
        elif not self.path.is_file():
            raise StoreError(f"{self.path}: no such log")
        try:
            uri = f"file:{self.path}?mode={'rwc' if writer else 'ro'}"
            self.db = sqlite3.connect(uri, uri=True, isolation_level=None, check_same_thread=False)
            self.db.execute("PRAGMA busy_timeout = 5000")
            self._check_or_create(synchronous)
        except sqlite3.DatabaseError as exc:
            self._release()
            raise StoreError(f"{self.path}: not a usable SQLite log ({exc})") from None
        except BaseException:
            self._release()
            raise

    # -- opening -------------------------------------------------------------------------------
    def _take_lock(self) -> int:
        """An exclusive flock on the file itself (SQLite's own locks are POSIX ones and unaffected);
        held until `close`, so a second writer fails at once instead of interleaving rows."""
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise StoreError(f"{self.path}: another process writes this log (one writer per file)") from None
        return fd

    def _release(self) -> None:
        if self._lock_fd is not None:
            os.close(self._lock_fd)
            self._lock_fd = None

    def _check_or_create(self, synchronous: Synchronous) -> None:
        db = self.db
        app = db.execute("PRAGMA application_id").fetchone()[0]
        version = db.execute("PRAGMA user_version").fetchone()[0]
        tables = db.execute("SELECT count(*) FROM sqlite_master").fetchone()[0]
        if app == 0 and version == 0 and tables == 0:
            if not self.writer:
                raise StoreError(f"{self.path}: empty file, not a coplane log")
            db.execute("PRAGMA journal_mode = WAL")
            db.executescript(
                f"BEGIN; {_SCHEMA} PRAGMA application_id = {APPLICATION_ID};"
                f" PRAGMA user_version = {SCHEMA_VERSION}; COMMIT;"
            )
        elif app != APPLICATION_ID:
            raise StoreError(f"{self.path}: not a coplane log (SQLite application id {app:#x})")
        elif version != SCHEMA_VERSION:
            raise StoreError(
                f"{self.path}: log schema version {version}, this coplane reads version {SCHEMA_VERSION}"
            )
        if self.writer:
            db.execute("PRAGMA journal_mode = WAL")
            db.execute(f"PRAGMA synchronous = {synchronous}")
        check = db.execute("PRAGMA quick_check").fetchone()[0]
        if check != "ok":
            raise StoreError(f"{self.path}: corrupt log ({check})")

    # -- writing -------------------------------------------------------------------------------
    def append(
        self,
        sol: SolutionMessage,
        payload: bytes | None = None,
        *,
        meta: dict[str, Any] | None = None,
        now: float | None = None,
    ) -> int:
        """Append one solution (its wire JSON: `payload` if the caller already encoded it) and,
        in the same transaction, `meta` entries; committed when this returns. Returns the row id."""
        if not self.writer:
            raise StoreError(f"{self.path}: opened read-only")
        body = payload.decode() if payload is not None else sol.model_dump_json(by_alias=True)
        t = time.time() if now is None else now
        db = self.db
        db.execute("BEGIN IMMEDIATE")
        try:
            cur = db.execute(
                "INSERT INTO solutions (fleet, method, generation, seq, week, tow, appended_unix_s, body)"
                " VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                (sol.fleet, sol.method, _generation(sol), sol.seq, sol.epoch.week, sol.epoch.tow, t, body),
            )
            rid = int(cur.lastrowid or 0)
            db.executemany(
                "INSERT OR IGNORE INTO solution_vehicles (vehicle_id, solution_id) VALUES (?, ?)",
                [(v.vehicle_id, rid) for v in sol.vehicles],
            )
            self._put_meta(meta or {})
            db.execute("COMMIT")
        except BaseException:
            db.execute("ROLLBACK")
            raise
        return rid

    def set_meta(self, **entries: Any) -> None:
        """Write meta entries (JSON values) in one committed transaction."""
        self.db.execute("BEGIN IMMEDIATE")
        try:
            self._put_meta(entries)
            self.db.execute("COMMIT")
        except BaseException:
            self.db.execute("ROLLBACK")
            raise

    def _put_meta(self, entries: dict[str, Any]) -> None:
        self.db.executemany(
            "INSERT INTO meta (key, value) VALUES (?, ?) ON CONFLICT (key) DO UPDATE SET value = excluded.value",
            [(k, json.dumps(v)) for k, v in entries.items()],
        )

    def prune(self, keep_last: int) -> int:
        """Delete all but the last `keep_last` solutions (a bounded log); returns how many went."""
        db = self.db
        db.execute("BEGIN IMMEDIATE")
        try:
            row = db.execute("SELECT max(id) FROM solutions").fetchone()
            cut = (row[0] or 0) - keep_last
            db.execute("DELETE FROM solution_vehicles WHERE solution_id <= ?", (cut,))
            n = db.execute("DELETE FROM solutions WHERE id <= ?", (cut,)).rowcount
            db.execute("COMMIT")
        except BaseException:
            db.execute("ROLLBACK")
            raise
        return int(n)

    # -- reading -------------------------------------------------------------------------------
    def meta(self, key: str, default: Any = None) -> Any:
        """A meta entry's JSON value (`default` when absent); an unreadable one is a StoreError
        naming the file and the key, like an unreadable solution row."""
        row = self.db.execute("SELECT value FROM meta WHERE key = ?", (key,)).fetchone()
        if row is None:
            return default
        try:
            return json.loads(row[0])
        except (TypeError, ValueError) as exc:
            raise StoreError(f"{self.path}: meta entry {key!r} is not valid JSON ({exc})") from None

    def _where(self, fleet: str | None, method: str | None) -> tuple[str, list[Any]]:
        conds, args = [], []
        if fleet is not None:
            conds.append("fleet = ?")
            args.append(fleet)
        if method is not None:
            conds.append("method = ?")
            args.append(method)
        return (" WHERE " + " AND ".join(conds) if conds else ""), args

    def _row(self, rid: int, appended: float, body: str) -> StoredSolution:
        try:
            return StoredSolution(rid, appended, SolutionMessage.model_validate_json(body))
        except ValueError as exc:
            raise StoreError(f"{self.path}: row {rid} is not a valid solution ({str(exc)[:200]})") from None

    def rows(
        self, fleet: str | None = None, method: str | None = None, after_id: int = 0
    ) -> Iterator[StoredSolution]:
        """Every logged solution (of `fleet`/`method` when given), in append order."""
        where, args = self._where(fleet, method)
        where += (" AND" if where else " WHERE") + " id > ?"
        cur = self.db.execute(
            f"SELECT id, appended_unix_s, body FROM solutions{where} ORDER BY id", [*args, after_id]
        )
        for rid, appended, body in cur:
            yield self._row(rid, appended, body)

    def solutions(self, fleet: str | None = None, method: str | None = None) -> list[SolutionMessage]:
        return [r.solution for r in self.rows(fleet, method)]

    def count(self, fleet: str | None = None, method: str | None = None) -> int:
        where, args = self._where(fleet, method)
        return int(self.db.execute(f"SELECT count(*) FROM solutions{where}", args).fetchone()[0])

    def last(self, fleet: str | None = None, method: str | None = None) -> StoredSolution | None:
        """The most recently appended solution."""
        where, args = self._where(fleet, method)
        row = self.db.execute(
            f"SELECT id, appended_unix_s, body FROM solutions{where} ORDER BY id DESC LIMIT 1", args
        ).fetchone()
        return None if row is None else self._row(*row)

    def last_per_vehicle(self, fleet: str, method: str) -> dict[str, StoredSolution]:
        """Vehicle id -> the last logged solution that has a state of that vehicle."""
        cur = self.db.execute(
            "SELECT v.vehicle_id, max(s.id) FROM solution_vehicles v JOIN solutions s ON s.id = v.solution_id"
            " WHERE s.fleet = ? AND s.method = ? GROUP BY v.vehicle_id",
            (fleet, method),
        )
        ids = dict(cur.fetchall())
        out: dict[str, StoredSolution] = {}
        cache: dict[int, StoredSolution] = {}
        for vid, rid in sorted(ids.items()):
            if rid not in cache:
                row = self.db.execute(
                    "SELECT id, appended_unix_s, body FROM solutions WHERE id = ?", (rid,)
                ).fetchone()
                cache[rid] = self._row(*row)
            out[vid] = cache[rid]
        return out

    # -- closing -------------------------------------------------------------------------------
    def close(self) -> None:
        try:
            self.db.close()
        finally:
            self._release()

    def __enter__(self) -> SolutionLog:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
