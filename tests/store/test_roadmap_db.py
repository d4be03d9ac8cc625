"""The road-surface map on disk: bit-exact round trip, atomic batches, kill -9, foreign files, copying."""

from __future__ import annotations

import dataclasses
import math
import os
import shutil
import signal
import sqlite3
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from coplane.roadmap import (
    ChangeEvent,
    PassEvidence,
    RoadMap,
    RoadMapConfig,
    TileKey,
    TilePlane,
    tile_centre,
    tile_corners_lonlat,
)
from coplane.store import SolutionLog, StoreError
from coplane.store.roadmap_db import SCHEMA_VERSION, RoadMapDb

# the synthetic map's few passes never fill the common residual's window, so its change is found
# on each pass's own z (the setting round-trips like any other)
CFG = RoadMapConfig(change_reference=False)
BASE = TileKey(267_600, 43_000)  # Munich-ish at 20 m


def synthetic_passes(seed: int, n_tiles: int = 6, t0: float = 1.4e9) -> list[PassEvidence]:
    """Passes over a few tiles with arbitrary floats; tile 0's road rises 0.8 m after 5 passes
    (a change) and tile 1 gets an outlier pass (a rejected pass with a z)."""
    rng = np.random.default_rng(seed)
    passes = []
    for i in range(n_tiles):
        key = TileKey(BASE.row + i // 3, BASE.col + i % 3)
        for k in range(8 + i):
            step = 0.8 if (i == 0 and k >= 5) else 0.0  # tile 0 changes
            bad = 4.0 if (i == 1 and k == 6) else 0.0  # tile 1 gets an outlier pass
            e = rng.uniform(-10, 10, 12)
            n = np.full(12, rng.choice([-1.75, 1.75]))
            u = 500.0 + 0.02 * e + step + bad + rng.normal(0, 0.1) + rng.normal(0, 0.02, 12)
            sig = rng.uniform(0.05, 0.3, 12)
            passes.append(
                PassEvidence(f"v{k % 3}", t0 + 30.0 * k + i, np.column_stack([e, n, u]), sig, key, 0.0)
            )
    return passes


def synthetic_map(seed: int = 4) -> tuple[RoadMap, list[ChangeEvent]]:
    m = RoadMap(CFG)
    changes = m.apply(synthetic_passes(seed))
    return m, changes


def same_tile(a: TilePlane, b: TilePlane) -> None:
    """Every field bit for bit (nan z compared as nan)."""
    for f in dataclasses.fields(TilePlane):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, np.ndarray):
            assert x.tobytes() == y.tobytes(), f.name
        elif f.name == "recent":
            assert len(x) == len(y)
            for p, q in zip(x, y, strict=True):
                for g in dataclasses.fields(p):
                    u, v = getattr(p, g.name), getattr(q, g.name)
                    if isinstance(u, np.ndarray):
                        assert u.tobytes() == v.tobytes(), g.name
                    elif isinstance(u, float) and math.isnan(u):
                        assert math.isnan(v)
                    else:
                        assert u == v and type(u) is type(v), g.name
        else:
            assert x == y and type(x) is type(y), f.name


def test_round_trip_is_bit_exact(tmp_path: Path) -> None:
    m, changes = synthetic_map()
    assert len(changes) == 1 and any(t.outlier_passes for t in m.tiles.values())
    path = tmp_path / "map.sqlite"
    with RoadMapDb(path, CFG) as db:
        assert db.write(m.take_dirty(), changes, now=1234.5) == len(m.tiles)
    with RoadMapDb(path, readonly=True) as db:
        loaded = db.load()
        assert loaded.config == CFG and loaded.dirty == set()
        assert loaded.tiles.keys() == m.tiles.keys()
        for k in m.tiles:
            same_tile(m.tiles[k], loaded.tiles[k])
        (c,) = db.changes()
        assert c == {
            "id": 1,
            "tile": str(changes[0].key),
            "time_s": changes[0].time_s,
            "old_height_m": changes[0].old_height_m,
            "new_height_m": changes[0].new_height_m,
            "passes_used": changes[0].passes_used,
            "recorded_unix_s": 1234.5,
        }
        some = [BASE, TileKey(BASE.row + 1, BASE.col + 2), TileKey(0, 0)]
        got = db.load_keys(some)
        assert sorted(got) == some[:2]
        same_tile(got[BASE], m.tiles[BASE])
        assert db.count() == len(m.tiles)
    # the loaded map keeps learning exactly like the original (CUSUM state and recent passes too)
    more = synthetic_passes(seed=5, t0=1.5e9)
    assert m.apply(more) == loaded.apply(more)
    for k in m.tiles:
        same_tile(m.tiles[k], loaded.tiles[k])


def test_tiles_in_bbox_uses_the_grid(tmp_path: Path) -> None:
    m, changes = synthetic_map()
    with RoadMapDb(tmp_path / "m.sqlite") as db:
        db.write(m.tiles.values(), changes)
        lat, lon = tile_centre(BASE, CFG.tile_size_m)
        d = 1e-5  # ~1 m around the centre of BASE only
        inside = db.tiles_in_bbox(
            math.degrees(lon) - d, math.degrees(lat) - d, math.degrees(lon) + d, math.degrees(lat) + d
        )
        assert [t.key for t in inside] == [BASE]
        big = db.tiles_in_bbox(
            math.degrees(lon) - 0.01,
            math.degrees(lat) - 0.01,
            math.degrees(lon) + 0.01,
            math.degrees(lat) + 0.01,
        )
        assert [t.key for t in big] == sorted(m.tiles)


def test_a_batch_is_atomic(tmp_path: Path) -> None:
    m, _ = synthetic_map()
    path = tmp_path / "m.sqlite"
    with RoadMapDb(path) as db:
        tiles = list(m.tiles.values())
        db.write(tiles[:2])
        bad = ChangeEvent(BASE, 1.0, None, 2.0, 3)  # type: ignore[arg-type]  # NOT NULL fails mid-batch
        with pytest.raises(sqlite3.IntegrityError):
            db.write(tiles[2:], [bad])
        assert db.count() == 2 and db.changes() == []
        db.write(tiles[2:])
        assert db.count() == len(tiles)


WRITER = textwrap.dedent(
    """
    import sys, dataclasses
    import numpy as np
    from coplane.roadmap import RoadMapConfig, TileKey, TilePlane, ChangeEvent
    from coplane.store.roadmap_db import RoadMapDb
    db = RoadMapDb(sys.argv[1])
    tiles = [TilePlane(TileKey(100, c), 500.0, info=np.eye(3)) for c in range(200)]
    v = 0
    while True:
        v += 1
        batch = [dataclasses.replace(t, version=v, n_passes=v) for t in tiles]
        db.write(batch, [ChangeEvent(TileKey(100, 0), float(v), 0.0, 1.0, v)])
        if v == 3:
            print("writing", flush=True)
    """
)


def test_kill_9_mid_write_leaves_a_consistent_map(tmp_path: Path) -> None:
    path = tmp_path / "m.sqlite"
    proc = subprocess.Popen([sys.executable, "-c", WRITER, str(path)], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None and proc.stdout.readline().strip() == "writing"
        time.sleep(0.4)
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.wait(timeout=10)
    assert proc.returncode == -signal.SIGKILL
    with RoadMapDb(path) as db:  # opens: schema, application id and quick_check pass
        m = db.load()
        versions = {t.version for t in m.tiles.values()}
        assert len(m.tiles) == 200 and len(versions) == 1  # never half a batch
        (v,) = versions
        assert v >= 3 and [c["passes_used"] for c in db.changes(limit=1)] == [v]
        assert len(db.changes(limit=10**6)) == v  # one change row per committed batch


def test_foreign_corrupt_and_newer_files_are_errors_naming_the_file(tmp_path: Path) -> None:
    junk = tmp_path / "junk.sqlite"
    junk.write_bytes(b"this is not a database, just some bytes" * 200)
    with pytest.raises(StoreError, match=r"junk\.sqlite"):
        RoadMapDb(junk)
    log = tmp_path / "log.sqlite"
    SolutionLog(log).close()
    with pytest.raises(
        StoreError, match=r"log.sqlite: not a coplane map \(SQLite application id 0x63706c6e\)"
    ):
        RoadMapDb(log)
    newer = tmp_path / "newer.sqlite"
    RoadMapDb(newer).close()
    con = sqlite3.connect(newer)
    con.execute(f"PRAGMA user_version = {SCHEMA_VERSION + 1}")
    con.close()
    with pytest.raises(StoreError, match=rf"newer\.sqlite: map schema version {SCHEMA_VERSION + 1}"):
        RoadMapDb(newer, readonly=True)
    with pytest.raises(StoreError, match=r"missing\.sqlite: no such map file"):
        RoadMapDb(tmp_path / "missing.sqlite", readonly=True)
    empty = tmp_path / "empty.sqlite"
    empty.touch()
    with pytest.raises(StoreError, match=r"empty\.sqlite: empty file"):
        RoadMapDb(empty, readonly=True)
    with RoadMapDb(tmp_path / "ro.sqlite") as db:
        pass
    with RoadMapDb(tmp_path / "ro.sqlite", readonly=True) as db, pytest.raises(StoreError, match="read-only"):
        db.write([])


def test_the_stored_tile_size_wins(tmp_path: Path) -> None:
    path = tmp_path / "m.sqlite"
    cfg = dataclasses.replace(CFG, tile_size_m=25.0, min_passes=3)
    RoadMapDb(path, cfg).close()
    with RoadMapDb.open(path) as db:
        assert db.config == cfg and db.load().config == cfg
    other = dataclasses.replace(cfg, outlier_z=4.0)  # same tiles, other thresholds: allowed
    with RoadMapDb(path, other) as db:
        assert db.config == other
    with pytest.raises(
        StoreError, match=r"m.sqlite: the map's tiles are 25 m, the configuration asks for 20 m"
    ):
        RoadMapDb(path, CFG)


def test_a_closed_map_is_one_file_that_can_be_copied(tmp_path: Path) -> None:
    m, changes = synthetic_map()
    path = tmp_path / "a" / "m.sqlite"
    db = RoadMapDb(path)
    reader = RoadMapDb(path, readonly=True)  # another process may read while one writes
    db.write(m.tiles.values(), changes)
    assert reader.count() == len(m.tiles)
    reader.close()
    db.close()
    wal = path.with_name(path.name + "-wal")
    assert not wal.exists() or wal.stat().st_size == 0
    copy = tmp_path / "b" / "copy.sqlite"
    copy.parent.mkdir()
    shutil.copy(path, copy)  # the main file only
    with RoadMapDb(copy, readonly=True) as db2:
        loaded = db2.load()
        assert len(db2.changes()) == 1
    for k in m.tiles:
        same_tile(m.tiles[k], loaded.tiles[k])


@pytest.mark.parametrize(
    ("sql", "reason"),
    [
        ("UPDATE tiles SET h0_m = 1e6", "height out of range"),
        # SQLite stores a NaN REAL as NULL (refused: NOT NULL); as text it gets in
        ("UPDATE tiles SET h0_m = 'NaN'", "height out of range"),
        ("UPDATE tiles SET i11 = -1e6", "information matrix not positive definite"),
        ("UPDATE tiles SET i00 = -0.5", "information matrix not positive definite"),
        ("UPDATE tiles SET i01 = i00 * 1e3", "information matrix not positive definite"),
        ("UPDATE tiles SET i22 = 9e999", "non-finite information"),
        ("UPDATE tiles SET eta0 = 'x'", "unreadable row"),
        ("UPDATE tiles SET n_passes = -3", "negative count"),
        ("UPDATE tiles SET cusum_neg_n = -1", "negative count"),
        ("UPDATE tiles SET n_passes = 9e999", "unreadable row (OverflowError)"),
        ("UPDATE tiles SET updated_s = 'NaN'", "time not finite"),
        ("UPDATE tiles SET cusum_pos = -9e999", "change detector state invalid"),
        ("UPDATE tiles SET row = 1000000000", "tile key outside the grid"),
        ("UPDATE tiles SET recent = '[{\"t\": 1}]'", "unreadable row"),
        ("UPDATE tiles SET recent = 'garbage, not JSON'", "unreadable row"),
        ("UPDATE tiles SET recent = x'00ff10'", "unreadable row"),
        ("UPDATE tiles SET recent = '{\"a\": 1}'", "unreadable row"),
        (
            "UPDATE tiles SET recent = '" + "[" * 100_000 + "]" * 100_000 + "'",
            "unreadable row (RecursionError)",
        ),
        # a pass summary's fields: too many numbers, an infinite count, NaN where JSON allows it
        ("UPDATE tiles SET recent = replace(recent, '\"info\": [', '\"info\": [1.0, ')", "unreadable row"),
        ('UPDATE tiles SET recent = replace(recent, \'"n": \', \'"n": 1e999, "x": \')', "unreadable row"),
        ("UPDATE tiles SET recent = replace(recent, '\"eta\": [', '\"eta\": [NaN, ')", "invalid recent pass"),
        (
            'UPDATE tiles SET recent = replace(recent, \'"info": [\', \'"info": [NaN, 0, 0, 0, 0, 0], "x": [\')',
            "invalid recent pass",
        ),
        (
            'UPDATE tiles SET recent = replace(recent, \'"info": [\', \'"info": [-1, 0, 0, 0, 0, 0], "x": [\')',
            "invalid recent pass",
        ),
        ('UPDATE tiles SET recent = replace(recent, \'"t": \', \'"t": NaN, "x": \')', "invalid recent pass"),
    ],
)
def test_damaged_rows_are_skipped_counted_and_the_rest_kept(tmp_path: Path, sql: str, reason: str) -> None:
    """A tampered or bit-rotted row costs itself: the other tiles load bit for bit."""

    m, changes = synthetic_map()
    path = tmp_path / "map.sqlite"
    with RoadMapDb(path) as db:
        db.write(m.take_dirty(), changes)
    con = sqlite3.connect(path)
    con.execute(sql + " WHERE row = ? AND col = ?", (BASE.row, BASE.col))
    con.commit()
    con.close()
    with RoadMapDb(path, readonly=True) as db:
        loaded = db.load()
        assert set(loaded.tiles) == set(m.tiles) - {BASE}
        for k in loaded.tiles:
            same_tile(m.tiles[k], loaded.tiles[k])
        assert sum(n for why, n in db.rejected.items() if why.startswith(reason)) == 1, db.rejected
        assert db.load_keys([BASE]) == {}


def test_damaged_rows_are_logged_once_per_reason_naming_tile_and_file(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """Every read path (load, load_keys, tiles_in_bbox) skips and counts the same bad rows; the log
    names the file and the tile once per reason, not once per row; the good tiles come back whole."""
    m, changes = synthetic_map()
    path = tmp_path / "map.sqlite"
    with RoadMapDb(path) as db:
        db.write(m.take_dirty(), changes)
    keys = sorted(m.tiles)
    nan_h0, bad_recent = keys[:2], keys[2]
    con = sqlite3.connect(path)
    for k in nan_h0:
        con.execute("UPDATE tiles SET h0_m = 'NaN' WHERE row = ? AND col = ?", (k.row, k.col))
    con.execute(
        "UPDATE tiles SET recent = '[1, 2' WHERE row = ? AND col = ?", (bad_recent.row, bad_recent.col)
    )
    con.commit()
    con.close()
    good = set(keys) - {*nan_h0, bad_recent}
    with caplog.at_level("WARNING", logger="coplane.store.roadmap_db"), RoadMapDb(path, readonly=True) as db:
        loaded = db.load()
        assert set(loaded.tiles) == good
        assert db.rejected == {"height out of range": 2, "unreadable row (JSONDecodeError)": 1}
        got = db.load_keys(keys)
        lon, lat = zip(*(xy for k in keys for xy in tile_corners_lonlat(k, CFG.tile_size_m)), strict=True)
        boxed = db.tiles_in_bbox(min(lon), min(lat), max(lon), max(lat))
        assert set(got) == good and {t.key for t in boxed} == good
        for t in [*got.values(), *boxed]:
            same_tile(m.tiles[t.key], t)
        assert db.rejected == {"height out of range": 6, "unreadable row (JSONDecodeError)": 3}
    records = [r for r in caplog.records if r.name == "coplane.store.roadmap_db"]
    assert len(records) == 2, [r.getMessage() for r in records]
    by_reason = {r.reason: r for r in records}  # type: ignore[attr-defined]
    first = by_reason["height out of range"]
    assert str(path) in first.getMessage() and str(nan_h0[0]) in first.getMessage()
    assert first.tile == str(nan_h0[0]) and first.path == str(path)  # type: ignore[attr-defined]
    assert str(bad_recent) in by_reason["unreadable row (JSONDecodeError)"].getMessage()


def test_mapped_until_is_stored_with_the_batch(tmp_path: Path) -> None:
    """The vehicles' newest mapped pass times travel with the tiles, in the same transaction."""
    m, changes = synthetic_map()
    assert set(m.mapped_until) == {"v0", "v1", "v2"}
    path = tmp_path / "map.sqlite"
    with RoadMapDb(path) as db:
        db.write(m.take_dirty(), changes, mapped_until=m.mapped_until)
    with RoadMapDb(path, readonly=True) as db:
        loaded = db.load()
    assert loaded.mapped_until == m.mapped_until
    last = m.mapped_until["v0"]
    assert loaded.is_mapped("v0", last) and not loaded.is_mapped("v0", last + 1.0)
    assert not loaded.is_mapped("v9", 0.0)


def test_a_damaged_mapped_until_entry_is_dropped_and_counted(tmp_path: Path) -> None:
    """A JSON integer beyond a float's range (OverflowError in float()) or a non-number in the
    vehicles' mapped-until times costs that entry, never the map."""
    m, changes = synthetic_map()
    path = tmp_path / "map.sqlite"
    with RoadMapDb(path) as db:
        db.write(m.take_dirty(), changes, mapped_until=m.mapped_until)
    con = sqlite3.connect(path)
    con.execute(
        "UPDATE meta SET value = ? WHERE key = 'mapped_until'",
        ('{"v0": 1' + "0" * 400 + ', "v1": "soon", "v2": 12.5}',),
    )
    con.commit()
    con.close()
    with RoadMapDb(path, readonly=True) as db:
        loaded = db.load()
        assert db.rejected == {"bad mapped_until entry": 2}
    assert loaded.mapped_until == {"v2": 12.5} and len(loaded.tiles) == len(m.tiles)


@pytest.mark.parametrize("config", ["[1, 2]", '{"tile_size_m": 1' + "0" * 400 + "}", "{"])
def test_an_unreadable_map_configuration_is_an_error_naming_the_file(tmp_path: Path, config: str) -> None:
    path = tmp_path / "map.sqlite"
    RoadMapDb(path).close()
    con = sqlite3.connect(path)
    con.execute("UPDATE meta SET value = ? WHERE key = 'config'", (config,))
    con.commit()
    con.close()
    with pytest.raises(StoreError, match=r"map\.sqlite: unreadable map configuration"):
        RoadMapDb(path, readonly=True)
