"""The solution log: round trip, errors that name the file, one writer, and crash safety."""

from __future__ import annotations

import os
import signal
import sqlite3
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
from support.api import SyntheticFleet

from coplane.store import SCHEMA_VERSION, SolutionLog, StoreError, log_path


def test_round_trip_in_order_with_indexed_columns(tmp_path: Path) -> None:
    fleet = SyntheticFleet(n_vehicles=3, n_epochs=5)
    path = tmp_path / "log.sqlite"
    sols = [fleet.solution(k) for k in range(5)]
    with SolutionLog(path) as lg:
        for s in sols:
            lg.append(s, now=1000.0 + s.seq)
        assert lg.count() == 5
    with SolutionLog(path, writer=False) as r:
        assert r.solutions() == sols  # exactly the wire models, in append order
        assert [row.appended_unix_s for row in r.rows()] == [1000.0 + k for k in range(5)]
        assert r.count(fleet=sols[0].fleet, method="pc") == 5
        assert r.count(method="other") == 0
        last = r.last()
        assert last is not None and last.solution == sols[-1]
        per = r.last_per_vehicle(sols[0].fleet, "pc")
        assert sorted(per) == fleet.ids and all(row.solution == sols[-1] for row in per.values())
        cols = r.db.execute("SELECT fleet, method, seq, week, tow FROM solutions ORDER BY id").fetchall()
        assert cols == [(s.fleet, s.method, s.seq, s.epoch.week, s.epoch.tow) for s in sols]


def test_last_per_vehicle_and_meta(tmp_path: Path) -> None:
    fleet = SyntheticFleet(n_vehicles=2, n_epochs=3)
    a, b = fleet.solution(0), fleet.solution(1)
    only_v1 = b.model_copy(update={"vehicles": b.vehicles[:1], "seq": 2})
    with SolutionLog(tmp_path / "l.sqlite") as lg:
        lg.append(a, meta={"server": {"epochs_solved": 1}})
        lg.append(only_v1, meta={"server": {"epochs_solved": 2}})
        per = lg.last_per_vehicle(a.fleet, "pc")
        assert per["v1"].solution == only_v1 and per["v2"].solution == a
        assert lg.meta("server") == {"epochs_solved": 2}
        assert lg.meta("missing", 7) == 7
        assert lg.prune(keep_last=1) == 1
        assert lg.solutions() == [only_v1]


def test_payload_is_kept_as_given(tmp_path: Path) -> None:
    sol = SyntheticFleet(n_vehicles=1, n_epochs=1).solution(0)
    payload = sol.model_dump_json(by_alias=True).encode()
    with SolutionLog(tmp_path / "l.sqlite") as lg:
        lg.append(sol, payload)
        assert lg.db.execute("SELECT body FROM solutions").fetchone()[0].encode() == payload


def test_corrupt_foreign_and_newer_files_are_errors_naming_the_file(tmp_path: Path) -> None:
    junk = tmp_path / "junk.sqlite"
    junk.write_bytes(b"this is not a database at all" * 100)
    for writer in (True, False):
        with pytest.raises(StoreError, match=r"junk\.sqlite"):
            SolutionLog(junk, writer=writer)
    foreign = tmp_path / "foreign.sqlite"
    with sqlite3.connect(foreign) as db:
        db.execute("CREATE TABLE t (x)")
    with pytest.raises(StoreError, match=r"foreign\.sqlite: not a coplane log"):
        SolutionLog(foreign)
    newer = tmp_path / "newer.sqlite"
    SolutionLog(newer).close()
    with sqlite3.connect(newer) as db:
        db.execute(f"PRAGMA user_version = {SCHEMA_VERSION + 1}")
    with pytest.raises(StoreError, match=rf"newer\.sqlite: log schema version {SCHEMA_VERSION + 1}"):
        SolutionLog(newer, writer=False)
    with pytest.raises(StoreError, match="no such log"):
        SolutionLog(tmp_path / "absent.sqlite", writer=False)
    # a log whose page was overwritten in the middle
    broken = tmp_path / "broken.sqlite"
    with SolutionLog(broken) as lg:
        fleet = SyntheticFleet(n_vehicles=4, n_epochs=40)
        for k in range(40):
            lg.append(fleet.solution(k))
        lg.db.execute("PRAGMA wal_checkpoint(TRUNCATE)")
    data = bytearray(broken.read_bytes())
    data[4096 + 100 : 4096 * 3] = b"\xff" * (4096 * 2 - 100)
    broken.write_bytes(bytes(data))
    with pytest.raises(StoreError, match=r"broken\.sqlite"):
        SolutionLog(broken, writer=False)


def test_one_writer_per_file_readers_welcome(tmp_path: Path) -> None:
    path = tmp_path / "l.sqlite"
    sol = SyntheticFleet(n_vehicles=1, n_epochs=1).solution(0)
    with SolutionLog(path) as w:
        with pytest.raises(StoreError, match="another process writes"):
            SolutionLog(path)
        w.append(sol)
        with SolutionLog(path, writer=False) as r:
            assert r.solutions() == [sol]
            with pytest.raises(StoreError, match="read-only"):
                r.append(sol)
    SolutionLog(path).close()  # the lock went with the writer


def test_log_path_settings(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("COPLANE_STATE_DIR", str(tmp_path))
    assert log_path("none", "fusion", "f") is None
    assert log_path("", "fusion", "f") is None
    assert log_path("/x/y.sqlite", "fusion", "f") == Path("/x/y.sqlite")
    got = log_path("auto", "fusion", "f", "pc", connect=["tcp/127.0.0.1:7447"])
    assert got == tmp_path / "fusion-f-pc-tcp-127.0.0.1-7447.sqlite"


CHILD = textwrap.dedent(
    """
    import sys
    from support.api import SyntheticFleet
    from coplane.store import SolutionLog
    fleet = SyntheticFleet(n_vehicles=4, n_epochs=50)
    sols = [fleet.solution(k) for k in range(50)]
    lg = SolutionLog(sys.argv[1], synchronous=sys.argv[2])
    k = 0
    while True:
        lg.append(sols[k % 50].model_copy(update={"seq": k}))
        print(k, flush=True)  # only after append returned, i.e. committed
        k += 1
    """
)


@pytest.mark.parametrize("synchronous", ["NORMAL", "FULL"])
def test_every_returned_append_survives_sigkill(tmp_path: Path, synchronous: str) -> None:
    path = tmp_path / "crash.sqlite"
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    p = subprocess.Popen(
        [sys.executable, "-c", CHILD, str(path), synchronous], stdout=subprocess.PIPE, env=env, text=True
    )
    assert p.stdout is not None
    acked = -1
    deadline = time.monotonic() + 60
    while acked < 30 and time.monotonic() < deadline:
        line = p.stdout.readline()
        if not line:
            break
        acked = int(line)
    p.send_signal(signal.SIGKILL)  # mid-append, most likely
    rest = p.stdout.read()
    p.wait()
    if rest.strip():
        acked = int(rest.split()[-1])
    assert acked >= 30, "the child never got going"
    with SolutionLog(path) as lg:  # a writer: recovers the WAL as after any crash
        seqs = [s.seq for s in lg.solutions()]
    assert seqs[: acked + 1] == list(range(acked + 1))  # every acknowledged append is there
    assert seqs == list(range(len(seqs)))  # and nothing torn or out of order after it
