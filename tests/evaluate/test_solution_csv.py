"""The solution CSV (`coplane eval --out`, `coplane fleet --out`): a run over the bus collects the
fusion server's solutions and never sees the agents' node messages, so every column of the CSV
must come from the solutions alone to read the same as the in-process run's."""

from __future__ import annotations

import csv
import dataclasses
from collections import defaultdict
from pathlib import Path

from coplane.evaluate.report import write_solutions
from coplane.evaluate.runner import run_method
from coplane.recording.reader import open_recording
from coplane.sim.generate import run_simulation, write_recording


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open() as fh:
        return list(csv.DictReader(fh))


def test_the_csv_says_the_same_without_the_node_messages(tmp_path: Path) -> None:
    rec = open_recording(write_recording(run_simulation("urban-loop", 3, 60.0, 4), tmp_path / "rec"))
    run = run_method(rec, "pc")
    assert run.planes  # the in-process run saw the node messages' planes
    bus_like = dataclasses.replace(run, planes=defaultdict(dict))  # what `coplane fleet` collects
    ours = write_solutions(run, tmp_path / "in-process")
    theirs = write_solutions(bus_like, tmp_path / "bus")
    assert [p.name for p in ours] == [p.name for p in theirs] == ["u1.csv", "u2.csv", "u3.csv"]
    rows = [r for p in ours for r in _rows(p)]
    assert rows == [r for p in theirs for r in _rows(p)]
    # the plane columns are filled: a plane used and where it came from, and why one was not
    assert {r["plane_source"] for r in rows if r["plane"] == "used"} == {"fleet"}
    assert any(r["plane"].startswith("unavailable: ") for r in rows), {r["plane"] for r in rows}
