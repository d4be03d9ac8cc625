"""`RoadMapDb`: the road-surface map on disk, one SQLite file (docs/roadmap.md, "Storage").

Why SQLite and not DuckDB: SQLite is in the standard library and keeps the map in one file; its
transactions are row-level and atomic, so a `kill -9` during `write` loses at most that batch and
never leaves half a batch; in WAL mode other processes read while one writes (the fusion server
refines the map, the API and vehicle agents read tiles around them). DuckDB is columnar, built for
analytic scans over many rows, and would be a new compiled dependency for point reads by key.

Several processes may open one file; writes are serialised by SQLite (one writer at a time, the
others wait up to `BUSY_TIMEOUT_MS`). Each `write` stores whole tiles, so two processes writing the
same tile from their own in-memory maps would overwrite each other: give a map one refining writer.

The file carries an application id ("cpmp") and a schema version (`PRAGMA user_version`); a foreign
or corrupt file or a newer schema is a `StoreError` naming the file. `close()` checkpoints the WAL
into the main file and truncates it, so after a clean close the one `.sqlite` file is the whole map
and can be copied to another machine.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import sqlite3
import time
from collections import Counter
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from coplane.roadmap.config import RoadMapConfig
from coplane.roadmap.grid import TileKey
from coplane.roadmap.grid import row_col_ranges as _row_col_ranges
from coplane.roadmap.roadmap import RoadMap
from coplane.roadmap.tile import ChangeEvent, PassSummary, TilePlane
from coplane.store.log import StoreError

log = logging.getLogger("coplane.store.roadmap_db")

APPLICATION_ID = 0x63706D70  # "cpmp": marks a file as a coplane road-surface map
SCHEMA_VERSION = 1
BUSY_TIMEOUT_MS = 10000
_UPPER = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))  # the 6 numbers of a symmetric 3x3

_SCHEMA = """
CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE tiles (
    row INTEGER NOT NULL,
    col INTEGER NOT NULL,
    h0_m REAL NOT NULL,
    i00 REAL NOT NULL, i01 REAL NOT NULL, i02 REAL NOT NULL,
    i11 REAL NOT NULL, i12 REAL NOT NULL, i22 REAL NOT NULL,
    eta0 REAL NOT NULL, eta1 REAL NOT NULL, eta2 REAL NOT NULL,
    n_passes INTEGER NOT NULL,
    n_points INTEGER NOT NULL,
    outlier_passes INTEGER NOT NULL,
    cusum_pos REAL NOT NULL,
    cusum_neg REAL NOT NULL,
    cusum_pos_n INTEGER NOT NULL,
    cusum_neg_n INTEGER NOT NULL,
    changes INTEGER NOT NULL,
    version INTEGER NOT NULL,
    updated_s REAL NOT NULL,
    recent TEXT NOT NULL,
    PRIMARY KEY (row, col)
) WITHOUT ROWID;
CREATE TABLE changes (
    id INTEGER PRIMARY KEY,
    row INTEGER NOT NULL,
    col INTEGER NOT NULL,
    time_s REAL NOT NULL,
    old_height_m REAL NOT NULL,
    new_height_m REAL NOT NULL,
    passes_used INTEGER NOT NULL,
    recorded_unix_s REAL NOT NULL
);
CREATE INDEX changes_by_tile ON changes (row, col, id);
"""
_TILE_COLS = (
    "row, col, h0_m, i00, i01, i02, i11, i12, i22, eta0, eta1, eta2, n_passes, n_points, outlier_passes,"
    " cusum_pos, cusum_neg, cusum_pos_n, cusum_neg_n, changes, version, updated_s, recent"
)


def _sym6(m: np.ndarray) -> list[float]:
    return [float(m[i, j]) for i, j in _UPPER]


def _mat(v: Iterable[float]) -> np.ndarray:
    m = np.zeros((3, 3))
    for (i, j), x in zip(_UPPER, v, strict=True):
        m[i, j] = m[j, i] = x
    return m


def _recent_json(recent: list[PassSummary]) -> str:
    """Pass summaries as strict JSON (nan z -> null); Python's float repr round-trips bit-exactly."""
    return json.dumps(
        [
            {
                "t": p.time_s,
                "v": p.vehicle_id,
                "info": _sym6(p.info),
                "eta": [float(x) for x in p.eta],
                "n": p.n_points,
                "z": p.z if math.isfinite(p.z) else None,
                "ok": p.accepted,
            }
            for p in recent
        ],
        allow_nan=False,
    )


def _recent_of(text: str) -> list[PassSummary]:
    return [
        PassSummary(
            float(d["t"]),
            str(d["v"]),
            _mat(d["info"]),
            np.array(d["eta"], dtype=float),
            int(d["n"]),
            math.nan if d["z"] is None else float(d["z"]),
            bool(d["ok"]),
        )
        for d in json.loads(text)
    ]


def _row_of(t: TilePlane) -> tuple[Any, ...]:
    return (
        t.key.row, t.key.col, float(t.h0_m), *_sym6(t.info), *(float(x) for x in t.eta),
        t.n_passes, t.n_points, t.outlier_passes, float(t.cusum_pos), float(t.cusum_neg),
        t.cusum_pos_n, t.cusum_neg_n, t.changes, t.version, float(t.updated_s), _recent_json(t.recent),
    )  # fmt: skip


def _tile_of(r: tuple[Any, ...]) -> TilePlane:
    return TilePlane(
        key=TileKey(int(r[0]), int(r[1])),
        h0_m=float(r[2]),
        info=_mat(r[3:9]),
        eta=np.array(r[9:12], dtype=float),
        n_passes=int(r[12]),
        n_points=int(r[13]),
        outlier_passes=int(r[14]),
        cusum_pos=float(r[15]),
        cusum_neg=float(r[16]),
        cusum_pos_n=int(r[17]),
        cusum_neg_n=int(r[18]),
        changes=int(r[19]),
        version=int(r[20]),
        updated_s=float(r[21]),
        recent=_recent_of(r[22]),
    )


class RoadMapDb:
    """One map file. A new file is created (unless `readonly`) with `config` (default: defaults);
    an existing file keeps its stored tile size, and a `config` with another size is an error."""

    def __init__(
        self, path: Path | str, config: RoadMapConfig | None = None, *, readonly: bool = False
    ) -> None:
        self.path = Path(path)
        self.readonly = readonly
        self.rejected: Counter[str] = Counter()  # stored tiles skipped on reading, by reason
        if readonly and not self.path.is_file():
            raise StoreError(f"{self.path}: no such map file")
        if not readonly:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        try:
            uri = f"file:{self.path}?mode={'ro' if readonly else 'rwc'}"
            self.db = sqlite3.connect(uri, uri=True, isolation_level=None, check_same_thread=False)
            self.db.execute(f"PRAGMA busy_timeout = {BUSY_TIMEOUT_MS}")
            self.config = self._check_or_create(config)
        except sqlite3.DatabaseError as exc:
            self._close_quietly()
            raise StoreError(f"{self.path}: not a usable map file ({exc})") from None
        except BaseException:
            self._close_quietly()
            raise

    @classmethod
    def open(
        cls, path: Path | str, config: RoadMapConfig | None = None, *, readonly: bool = False
    ) -> RoadMapDb:
        return cls(path, config, readonly=readonly)

    # -- opening -------------------------------------------------------------------------------
    def _check_or_create(self, config: RoadMapConfig | None) -> RoadMapConfig:
        db = self.db
        app = db.execute("PRAGMA application_id").fetchone()[0]
        version = db.execute("PRAGMA user_version").fetchone()[0]
        n_tables = db.execute("SELECT count(*) FROM sqlite_master").fetchone()[0]
        if app == 0 and version == 0 and n_tables == 0:
            if self.readonly:
                raise StoreError(f"{self.path}: empty file, not a coplane map")
            return self._create(config or RoadMapConfig())
        if app != APPLICATION_ID:
            raise StoreError(f"{self.path}: not a coplane map (SQLite application id {app:#x})")
        if version != SCHEMA_VERSION:
            raise StoreError(
                f"{self.path}: map schema version {version}, this coplane reads version {SCHEMA_VERSION}"
            )
        if not self.readonly:
            db.execute("PRAGMA journal_mode = WAL")
            db.execute("PRAGMA synchronous = FULL")
        check = db.execute("PRAGMA quick_check").fetchone()[0]
        if check != "ok":
            raise StoreError(f"{self.path}: corrupt map ({check})")
        try:
            stored = RoadMapConfig.from_dict(json.loads(self._meta("config")))
        # not an object (AttributeError), or a number beyond a float's range (ArithmeticError)
        except (TypeError, ValueError, KeyError, AttributeError, ArithmeticError) as exc:
            raise StoreError(f"{self.path}: unreadable map configuration ({exc})") from None
        if config is None:
            return stored
        if config.tile_size_m != stored.tile_size_m:
            raise StoreError(
                f"{self.path}: the map's tiles are {stored.tile_size_m:g} m, the configuration asks for"
                f" {config.tile_size_m:g} m (a map's tile size cannot change)"
            )
        return config

    def _create(self, config: RoadMapConfig) -> RoadMapConfig:
        db = self.db
        db.execute("PRAGMA journal_mode = WAL")
        db.execute("PRAGMA synchronous = FULL")
        db.execute("BEGIN IMMEDIATE")
        try:
            if db.execute("SELECT count(*) FROM sqlite_master").fetchone()[0]:  # another process won
                db.execute("ROLLBACK")
                return self._check_or_create(config)
            for stmt in _SCHEMA.split(";"):
                if stmt.strip():
                    db.execute(stmt)
            db.execute(f"PRAGMA application_id = {APPLICATION_ID}")
            db.execute(f"PRAGMA user_version = {SCHEMA_VERSION}")
            meta = {
                "tile_size_m": json.dumps(config.tile_size_m),
                "config": json.dumps(config.to_dict()),
                "created_unix_s": json.dumps(time.time()),
            }
            db.executemany("INSERT INTO meta (key, value) VALUES (?, ?)", meta.items())
            db.execute("COMMIT")
        except BaseException:
            db.execute("ROLLBACK")
            raise
        return config

    def _meta(self, key: str) -> str:
        row = self.db.execute("SELECT value FROM meta WHERE key = ?", (key,)).fetchone()
        if row is None:
            raise KeyError(f"meta entry {key!r} is missing")
        return str(row[0])

    # -- writing -------------------------------------------------------------------------------
    def write(
        self,
        tiles: Iterable[TilePlane],
        changes: Iterable[ChangeEvent] = (),
        *,
        now: float | None = None,
        mapped_until: dict[str, float] | None = None,
    ) -> int:
        """Store whole tiles (insert or replace), change events and the vehicles' mapped-until
        times (RoadMap.mapped_until) in ONE transaction: after a crash the file holds all of this
        batch or none of it. Returns the number of tiles written."""
        if self.readonly:
            raise StoreError(f"{self.path}: opened read-only")
        rows = [_row_of(t) for t in tiles]
        t_rec = time.time() if now is None else float(now)
        events = [
            (c.key.row, c.key.col, c.time_s, c.old_height_m, c.new_height_m, c.passes_used, t_rec)
            for c in changes
        ]
        db = self.db
        db.execute("BEGIN IMMEDIATE")
        try:
            db.executemany(
                f"INSERT OR REPLACE INTO tiles ({_TILE_COLS}) VALUES ({', '.join('?' * 23)})", rows
            )
            db.executemany(
                "INSERT INTO changes (row, col, time_s, old_height_m, new_height_m, passes_used, recorded_unix_s)"
                " VALUES (?, ?, ?, ?, ?, ?, ?)",
                events,
            )
            if mapped_until is not None:
                db.execute(
                    "INSERT OR REPLACE INTO meta (key, value) VALUES ('mapped_until', ?)",
                    (json.dumps({str(k): float(v) for k, v in sorted(mapped_until.items())}),),
                )
            db.execute("COMMIT")
        except BaseException:
            db.execute("ROLLBACK")
            raise
        return len(rows)

    # -- reading -------------------------------------------------------------------------------
    def load(self) -> RoadMap:
        """The whole map in memory (nothing dirty); unreadable or invalid tiles are skipped."""
        cur = self.db.execute(f"SELECT {_TILE_COLS} FROM tiles ORDER BY row, col")
        return RoadMap(self.config, {t.key: t for t in self._valid(cur)}, self._mapped_until())

    def _mapped_until(self) -> dict[str, float]:
        """The vehicles' mapped-until times (absent in a map no pass was written to; a damaged
        entry is dropped and counted: at worst that vehicle's old evidence could count again)."""
        row = self.db.execute("SELECT value FROM meta WHERE key = 'mapped_until'").fetchone()
        if row is None:
            return {}
        try:
            raw = json.loads(row[0])
            items = raw.items() if isinstance(raw, dict) else ()
        except (TypeError, ValueError):
            self.rejected["unreadable mapped_until"] += 1
            return {}
        out = {}
        for k, v in items:
            # a JSON integer may be beyond a float's range: float() raises OverflowError there
            try:
                ok = isinstance(k, str) and isinstance(v, int | float) and math.isfinite(v)
            except OverflowError:
                ok = False
            if ok:
                out[k] = float(v)
            else:
                self.rejected["bad mapped_until entry"] += 1
        return out

    def _valid(self, rows: Iterable[tuple[Any, ...]]) -> list[TilePlane]:
        """The rows that parse into a tile fit to give a plane (TilePlane.problem); every other
        one is counted in `rejected` and logged once per reason, naming the tile and the file, so
        a damaged row costs itself and never the map (docs/roadmap.md, "Bad map input")."""
        out = []
        for r in rows:
            try:
                tile = _tile_of(r)
                why = tile.problem(self.config)
            # a garbled row: text for a number, an infinite count, JSON nested too deep, ...
            except (TypeError, ValueError, KeyError, IndexError, ArithmeticError, RecursionError) as exc:
                why = f"unreadable row ({type(exc).__name__})"
            if why is None:
                out.append(tile)
                continue
            if not self.rejected[why]:
                where = f"r{r[0]}c{r[1]}" if len(r) > 1 else "?"
                log.warning(
                    "%s: road map tile %s skipped: %s (further tiles skipped for this reason are only counted)",
                    self.path,
                    where,
                    why,
                    extra={"path": str(self.path), "tile": where, "reason": why},
                )
            self.rejected[why] += 1
        return out

    def load_keys(self, keys: Iterable[TileKey]) -> dict[TileKey, TilePlane]:
        """The stored tiles among `keys` (missing ones are simply absent)."""
        out: dict[TileKey, TilePlane] = {}
        for k in sorted(set(keys)):
            r = self.db.execute(
                f"SELECT {_TILE_COLS} FROM tiles WHERE row = ? AND col = ?", (k.row, k.col)
            ).fetchone()
            if r is not None:
                for tile in self._valid([r]):
                    out[k] = tile
        return out

    def tiles_in_bbox(
        self, min_lon: float, min_lat: float, max_lon: float, max_lat: float
    ) -> list[TilePlane]:
        """Stored tiles meeting a lon/lat box (degrees), by key: one range scan of the primary key
        per row of the grid, so the cost follows the tiles found, not the size of the map."""
        out: list[TilePlane] = []
        sql = f"SELECT {_TILE_COLS} FROM tiles WHERE row = ? AND col BETWEEN ? AND ? ORDER BY col"
        for row, c0, c1 in _row_col_ranges(min_lon, min_lat, max_lon, max_lat, self.config.tile_size_m):
            out.extend(self._valid(self.db.execute(sql, (row, c0, c1))))
        return out

    def changes(self, limit: int = 100) -> list[dict[str, Any]]:
        """The newest recorded changes first, as plain dicts (tile as its "r..c.." string)."""
        cur = self.db.execute(
            "SELECT id, row, col, time_s, old_height_m, new_height_m, passes_used, recorded_unix_s"
            " FROM changes ORDER BY id DESC LIMIT ?",
            (int(limit),),
        )
        return [
            {
                "id": r[0],
                "tile": str(TileKey(r[1], r[2])),
                "time_s": r[3],
                "old_height_m": r[4],
                "new_height_m": r[5],
                "passes_used": r[6],
                "recorded_unix_s": r[7],
            }
            for r in cur
        ]

    def count(self) -> int:
        return int(self.db.execute("SELECT count(*) FROM tiles").fetchone()[0])

    # -- closing -------------------------------------------------------------------------------
    def close(self) -> None:
        """Checkpoint the WAL into the main file and truncate it (a writer), then close: after
        this the `.sqlite` file alone is the whole map."""
        try:
            if not self.readonly:
                self.db.execute("PRAGMA wal_checkpoint(TRUNCATE)")
        finally:
            self.db.close()

    def _close_quietly(self) -> None:
        db = getattr(self, "db", None)
        if db is not None:
            with contextlib.suppress(sqlite3.Error):
                db.close()

    def __enter__(self) -> RoadMapDb:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
