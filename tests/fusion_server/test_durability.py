"""The fusion server's solution log: committed before publication, resumed after a crash.

The server is driven in-process (its `handle`/`solve` and the durability hooks of `run`), with the
node messages of a short simulated recording, so a "crash" is simply dropping the server without
its clean stop.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest

from coplane.bus import Payload, encode
from coplane.evaluate.runner import run_method
from coplane.fusion_server.server import FusionServer
from coplane.fusion_server.settings import FusionSettings
from coplane.gtime import GpsTime
from coplane.messages import NodeMessage, SolutionMessage
from coplane.recording.reader import open_recording
from coplane.sim.generate import simulate
from coplane.steps import gps_time
from coplane.store import SolutionLog


@dataclass
class Replay:
    recording: Path
    messages: list[dict[str, NodeMessage]]  # per epoch
    reference: list[SolutionMessage]  # the uninterrupted in-process run


@pytest.fixture(scope="module")
def replay(tmp_path_factory: pytest.TempPathFactory) -> Replay:
    rec = simulate("urban-loop", tmp_path_factory.mktemp("rec") / "r", vehicles=3, duration_s=14, seed=7)
    msgs: list[dict[str, NodeMessage]] = []
    sols: list[SolutionMessage] = []

    def keep(sol: SolutionMessage, m: dict[str, NodeMessage]) -> None:
        sols.append(sol)
        msgs.append(dict(m))

    run_method(open_recording(rec), "pc", on_solution=keep, jobs=1)
    return Replay(rec, msgs, sols)


@dataclass
class FakeNode:
    """What the server puts, in order (the bus side of `run`)."""

    puts: list[tuple[str, bytes]] = field(default_factory=list)

    def put(self, key: str, payload: bytes) -> None:
        self.puts.append((key, payload))


def _server(replay: Replay, db: Path) -> tuple[FusionServer, FakeNode]:
    s = FusionServer(FusionSettings(recording=replay.recording, db=str(db)))
    node = FakeNode()
    s.durable.start(s, now=0.0)
    s.live = set(s.known)
    return s, node


def _feed(s: FusionServer, node: FakeNode, replay: Replay, epochs: range) -> None:
    """Deliver these epochs' messages and solve what is ready, as `run` does."""
    for k in epochs:
        for vid, m in sorted(replay.messages[k].items()):
            s.handle(Payload(s.keys.node(vid), encode(m)))
        while (t := s.ready_epoch(1e9)) is not None:
            if (sol := s.solve(t)) is not None:
                s.durable.publish(s, node, s.keys.solution, sol)  # type: ignore[arg-type]


def _crash(s: FusionServer) -> None:
    """kill -9: the log is left as it is (only our file handle goes, to free the writer lock)."""
    assert s.durable.log is not None
    s.durable.log.close()
    s.durable.log = None


def test_resume_reseeds_and_never_resolves_a_logged_epoch(replay: Replay, tmp_path: Path) -> None:
    db = tmp_path / "fusion.sqlite"
    a, node_a = _server(replay, db)
    _feed(a, node_a, replay, range(8))
    published = [SolutionMessage.model_validate_json(p) for _, p in node_a.puts]
    assert [p.seq for p in published] == list(range(8))
    with SolutionLog(db, writer=False) as r:  # every published solution is on disk
        assert r.solutions() == published
    counters = {v: dict(c) for v, c in a.counters.items()}
    _crash(a)

    b, node_b = _server(replay, db)
    assert b.durable.resumed is not None and b.durable.resumed.seeds == 3
    assert b.step.seq == 8 and b.epochs_solved == 8
    assert b.solved_up_to == gps_time(published[-1].epoch)
    assert {v: dict(c) for v, c in b.counters.items()} == counters
    # live agents and nothing newer after a while: the last logged solution goes out again (its
    # publication may have died with the server, and lockstep agents would wait for it forever)
    b.durable.tick(b, node_b, b.keys.solution, now=1.0)  # type: ignore[arg-type]
    assert node_b.puts == []
    b.durable.tick(b, node_b, b.keys.solution, now=10.0)  # type: ignore[arg-type]
    assert SolutionMessage.model_validate_json(node_b.puts[0][1]) == published[-1]
    assert b.generation == a.generation == published[-1].generation  # a resume is the same run
    # the agents' caches replay epochs 4..7 (already solved) and the server goes on from 8
    _feed(b, node_b, replay, range(4, 14))
    after = [SolutionMessage.model_validate_json(p) for _, p in node_b.puts[1:]]
    assert [p.seq for p in after] == list(range(8, 14))
    assert {p.generation for p in after} == {a.generation}
    assert after[0].factor_counts.get("seed", 0) >= 3  # each vehicle resumed from its last state
    assert sum(c["late"] for c in b.counters.values()) == 3 * 4  # replays counted, not re-solved
    with SolutionLog(db, writer=False) as r:
        logged = r.solutions()
    epochs = [GpsTime(s.epoch.week, s.epoch.tow) for s in logged]
    assert epochs == sorted(set(epochs)) and len(logged) == 14  # no epoch twice, none missing
    # positions after the restart stay with the uninterrupted run
    ref = {(s.seq, v.vehicle_id): np.array(v.position_ecef_m) for s in replay.reference for v in s.vehicles}
    worst = max(
        float(np.linalg.norm(np.array(v.position_ecef_m) - ref[(s.seq, v.vehicle_id)]))
        for s in after
        for v in s.vehicles
    )
    assert worst < 5.0, worst
    _crash(b)
    c, node_c = _server(replay, db)
    assert c.step.seq == 14
    c.live = set()  # the agents are gone: nobody waits for a solution
    c.durable.tick(c, node_c, c.keys.solution, now=10.0)  # type: ignore[arg-type]
    assert node_c.puts == [] and not c.durable.republished
    c.durable.close()


def test_clean_stop_starts_a_new_run(replay: Replay, tmp_path: Path) -> None:
    db = tmp_path / "fusion.sqlite"
    a, node = _server(replay, db)
    _feed(a, node, replay, range(3))
    a.durable.close()  # SIGTERM path
    b, node_b = _server(replay, db)
    assert b.durable.resumed is None and b.step.seq == 0 and b.solved_up_to is None
    assert b.generation != a.generation  # a new run: consumers may reset
    assert node_b.puts == []
    b.durable.close()


def test_old_crash_is_not_resumed_and_db_none_disables(replay: Replay, tmp_path: Path) -> None:
    db = tmp_path / "fusion.sqlite"
    a, node = _server(replay, db)
    _feed(a, node, replay, range(2))
    _crash(a)
    b = FusionServer(FusionSettings(recording=replay.recording, db=str(db), resume_max_age_s=0.0))
    b.durable.start(b)
    assert b.durable.resumed is None and b.step.seq == 0
    b.durable.close()
    off = FusionServer(FusionSettings(recording=replay.recording, db="none"))
    assert off.durable.path is None
    n = FakeNode()
    off.durable.start(off)
    sol = replay.reference[0]
    off.durable.publish(off, n, off.keys.solution, sol)  # type: ignore[arg-type]
    assert n.puts == [(off.keys.solution, encode(sol.model_copy(update={"generation": off.generation})))]


def test_a_corrupt_log_stops_the_server_naming_the_file(replay: Replay, tmp_path: Path) -> None:
    from coplane.store import StoreError

    db = tmp_path / "fusion.sqlite"
    db.write_bytes(b"garbage" * 1000)
    with pytest.raises(StoreError, match=r"fusion\.sqlite"):  # at once, before the bus is opened
        FusionServer(FusionSettings(recording=replay.recording, db=str(db)))


def test_the_log_stays_bounded(replay: Replay, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from coplane.fusion_server import durability

    monkeypatch.setattr(durability, "KEEP_SOLUTIONS", 2)
    monkeypatch.setattr(durability, "PRUNE_EVERY", 3)
    db = tmp_path / "fusion.sqlite"
    a, node = _server(replay, db)
    _feed(a, node, replay, range(7))
    assert len(node.puts) == 7
    with SolutionLog(db, writer=False) as r:
        assert [s.seq for s in r.solutions()] == [4, 5, 6]  # pruned to 2 at the 6th append, then one more
    _crash(a)
    b, _ = _server(replay, db)  # prunes on start, and still resumes from the newest
    assert b.step.seq == 7 and b.epochs_solved == 7
    assert b.durable.log is not None and b.durable.log.count() == 2
    b.durable.close()


def test_damaged_counters_cost_only_the_counters(
    replay: Replay, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """A crashed run's diagnostics snapshot of the wrong shape: the server still resumes (seq,
    seeds), with its counters from zero and a warning; a meta entry that is not JSON at all is a
    StoreError naming the file, like a damaged solution row."""
    import sqlite3

    from coplane.store import StoreError

    db = tmp_path / "fusion.sqlite"
    a, node = _server(replay, db)
    _feed(a, node, replay, range(3))
    _crash(a)
    con = sqlite3.connect(db)
    bad = '{"epochs_solved": "many", "counters": [1, 2], "rejected": {"x": 1' + "0" * 400 + "}}"
    con.execute("UPDATE meta SET value = ? WHERE key = 'server'", (bad,))
    con.commit()
    con.close()
    with caplog.at_level("WARNING", logger="coplane.fusion_server"):
        b, _ = _server(replay, db)
    assert b.durable.resumed is not None and b.durable.resumed.seeds == 3 and b.step.seq == 3
    assert b.epochs_solved == 0 and not any(b.counters.values()) and not b.rejected_by_reason
    assert any("counters of the crashed run are unreadable" in r.getMessage() for r in caplog.records)
    _crash(b)
    con = sqlite3.connect(db)
    con.execute("UPDATE meta SET value = ? WHERE key = 'writer'", ("{not json",))
    con.commit()
    con.close()
    with pytest.raises(StoreError, match=r"fusion\.sqlite: meta entry 'writer' is not valid JSON"):
        _server(replay, db)
