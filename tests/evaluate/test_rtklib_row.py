"""The RTKLIB reference row: pyrtklib postpos on a recording, and its `coplane eval` hook."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

import coplane.evaluate.rtklib_row as rr
from coplane.evaluate.evaluation import evaluate
from coplane.evaluate.report import run_stats
from coplane.recording.reader import Recording, open_recording
from coplane.sim.generate import simulate


@pytest.fixture(scope="module")
def rec30(tmp_path_factory: pytest.TempPathFactory) -> Recording:
    path = simulate("urban-loop", tmp_path_factory.mktemp("rec30") / "rec", vehicles=2, duration_s=30, seed=2)
    return open_recording(Path(path))


def test_rtklib_processes_every_vehicle(rec30: Recording) -> None:
    res = rr.process_recording(rec30)
    assert res.mode == "dgps" and not res.failures
    # no carrier phase in the simulated RINEX: RTKLIB's DGPS falls back to single points
    assert "single" in res.note and "no DGPS solution" in res.note
    run = res.run
    assert run.method == "rtklib" and run.n_epochs == 30
    stats = run_stats(run, rec30)
    for vid, st in stats.items():
        assert st.availability > 0.8  # RTKLIB drops epochs that fail its chi-square test
        assert st.h_rmse_m < 20.0
        times = list(run.positions[vid])
        assert all(t == t.round_to(1.0) for t in times)
        for c in run.covariances[vid].values():
            assert np.min(np.linalg.eigvalsh(c)) > 0
    single = rr.process_recording(rec30, dgnss=False)
    assert single.mode == "single" and "no DGPS" not in single.note
    for vid in run.positions:  # the same single-point solutions either way
        t = next(iter(single.run.positions[vid]))
        assert np.allclose(single.run.positions[vid][t], run.positions[vid][t])


def test_eval_includes_the_rtklib_row(rec30: Recording, tmp_path: Path) -> None:
    ev = evaluate(rec30, ["rtklib"], out_dir=tmp_path)
    assert [r.label for r in ev.runs] == ["rtklib"] and "u1" in ev.stats["rtklib"]
    doc = json.loads((tmp_path / "accuracy.json").read_text())
    assert doc["notes"]["rtklib"].startswith("RTKLIB dgps")
    assert "| rtklib |" in (tmp_path / "accuracy.md").read_text()
    assert (tmp_path / "solutions" / "rtklib" / "u1.csv").exists()


@pytest.mark.filterwarnings("ignore:No artists with labels")
def test_eval_skips_rtklib_with_a_message_when_pyrtklib_is_missing(
    rec30: Recording, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture, tmp_path: Path
) -> None:
    monkeypatch.setitem(sys.modules, "pyrtklib", None)  # import pyrtklib -> ImportError
    reason = rr.rtklib_unavailable()
    assert reason is not None and "pyrtklib" in reason
    caplog.set_level("INFO", logger="coplane.evaluate")
    ev = evaluate(rec30, ["rtklib"], out_dir=tmp_path)
    assert not ev.runs and ev.notes["rtklib"].startswith("rtklib row skipped: pyrtklib is not importable")
    assert "rtklib row skipped" in caplog.text  # logged; `coplane eval` prints ev.notes
    assert "rtklib row skipped" in json.loads((tmp_path / "accuracy.json").read_text())["notes"]["rtklib"]
