"""Corrupt epoch time tags: reported and skipped, never a huge replay grid or a silent loss."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import pytest

from coplane.gtime import GpsTime
from coplane.recording.problems import RecordingError
from coplane.recording.reader import open_recording
from coplane.replay import MAX_REPLAY_EPOCHS, nominal_grid, vehicle_schedule
from coplane.sim.generate import simulate

EPOCH_LINE = re.compile(r"^> (\d{4}) ", re.MULTILINE)


@pytest.fixture(scope="module")
def small(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return simulate("urban-loop", tmp_path_factory.mktemp("rec") / "r", vehicles=2, duration_s=30.0, seed=5)


def _copy_with_year(src: Path, dst: Path, epoch_index: int, new_year: int) -> Path:
    """The recording with the year of one of u1's epoch lines replaced."""
    shutil.copytree(src, dst)
    obs = dst / "vehicles" / "u1.obs"
    text = obs.read_text()
    m = list(EPOCH_LINE.finditer(text))[epoch_index]
    obs.write_text(text[: m.start(1)] + str(new_year) + text[m.end(1) :])
    return dst


@pytest.mark.parametrize("where", [10, -1])
def test_a_corrupt_year_is_reported_and_only_that_epoch_is_lost(
    small: Path, tmp_path: Path, where: int
) -> None:
    """2024 -> 2094 in the middle (every later epoch used to be dropped as out of order) or at the
    end (the replay grid used to span 70 years and exhaust memory)."""
    n = len(open_recording(small).vehicle_epochs("u1"))
    year = int(EPOCH_LINE.findall((small / "vehicles" / "u1.obs").read_text())[where])
    rec = open_recording(_copy_with_year(small, tmp_path / "bad", where, year + 70))
    epochs = rec.vehicle_epochs("u1")
    assert len(epochs) == n - 1
    assert rec.problems.counts["epoch-time-jump"] == 1
    sched = vehicle_schedule(epochs, rec.manifest.interval_s)
    assert len(sched) <= n


def test_an_epoch_back_in_time_is_reported_and_skipped(small: Path, tmp_path: Path) -> None:
    n = len(open_recording(small).vehicle_epochs("u1"))
    year = int(EPOCH_LINE.findall((small / "vehicles" / "u1.obs").read_text())[12])
    rec = open_recording(_copy_with_year(small, tmp_path / "bad", 12, year - 1))
    assert len(rec.vehicle_epochs("u1")) == n - 1
    assert rec.problems.counts["non-monotonic-time"] == 1


def test_the_replay_grid_refuses_an_absurd_span() -> None:
    t0 = GpsTime(2300, 0.0)
    assert len(list(nominal_grid(t0, t0 + 10.0, 1.0))) == 11
    with pytest.raises(RecordingError, match="check the epoch time tags"):
        next(nominal_grid(t0, t0 + (MAX_REPLAY_EPOCHS + 5) * 1.0, 1.0))
