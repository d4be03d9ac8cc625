"""uwb.csv and truth CSV readers on hand-made broken files, and writer round trips."""

from __future__ import annotations

from pathlib import Path

import pytest

from coplane.gtime import GpsTime
from coplane.recording.csvfiles import read_truth, read_uwb, write_truth, write_uwb
from coplane.recording.model import TruthPoint, UwbRange
from coplane.recording.problems import Problems, RecordingError

BROKEN = Path(__file__).resolve().parents[1] / "data" / "broken"
FLEET = BROKEN / "fleet"
W = 2320


def test_uwb_bad_rows_are_reported_and_skipped() -> None:
    problems = Problems()
    rows = read_uwb(FLEET / "uwb.csv", problems, {"u1", "u2"}, max_range_m=500.0)
    assert [(p.kind, p.line) for p in problems.items] == [
        ("unknown-id", 4),
        ("nan-value", 5),
        ("absurd-value", 6),  # negative
        ("absurd-value", 7),  # beyond max_range_m
        ("malformed-row", 8),  # 4 fields
        ("non-monotonic-time", 11),
        ("duplicate-row", 12),  # same pair, same tag, reversed order
    ]
    # every other row, exactly as written (matching to epochs is the Recording's job)
    assert rows == [
        UwbRange(GpsTime(W, 116400.0), "u1", "u2", 14.732),
        UwbRange(GpsTime(W, 116400.02), "u2", "u1", 14.740),
        UwbRange(GpsTime(W, 116401.5), "u1", "u2", 14.8),
        UwbRange(GpsTime(W, 116402.0), "u1", "u2", 14.9),
        UwbRange(GpsTime(W, 116403.04), "u1", "u2", 15.2),
        UwbRange(GpsTime(W, 116405.0), "u1", "u2", 15.3),
    ]


def test_truth_extra_columns_ignored_bad_rows_skipped() -> None:
    problems = Problems()
    pts = read_truth(FLEET / "truth" / "u1.csv", problems)
    assert [(p.kind, p.line) for p in problems.items] == [
        ("non-monotonic-time", 4),
        ("nan-value", 5),
        ("malformed-row", 8),
        ("absurd-value", 9),  # (1, 2, 3) m is not near the Earth
    ]
    assert [p.time.tow for p in pts] == [116400.0, 116401.0, 116402.5, 116403.0]
    assert pts[1] == TruthPoint(GpsTime(W, 116401.0), (-3817681.3817, 3562839.9795, 3650158.3770))


def test_header_is_required() -> None:
    with pytest.raises(RecordingError, match=r"truth_no_header\.csv.*gps_week"):
        read_truth(BROKEN / "truth_no_header.csv", Problems())
    with pytest.raises(RecordingError, match=r"missing\.csv"):
        read_uwb(BROKEN / "missing.csv", Problems(), {"u1"})


def test_writers_round_trip(tmp_path: Path) -> None:
    ranges = [
        UwbRange(GpsTime(W, 0.0), "a", "b", 1.2345),
        UwbRange(GpsTime(W, 0.0), "a", "c", 499.9999),
        UwbRange(GpsTime(W, 604799.9999995), "b", "c", 12.0),
    ]
    p = write_uwb(tmp_path / "uwb.csv", ranges)
    problems = Problems()
    assert read_uwb(p, problems, {"a", "b", "c"}, 500.0) == ranges
    assert problems.total == 0
    pts = [TruthPoint(GpsTime(W, 270147.004), (-2418077.271, 5386069.6872, 2405174.1252))]
    q = write_truth(tmp_path / "t.csv", pts)
    assert read_truth(q, problems) == pts
    assert q.read_text().splitlines()[0] == "gps_week,tow_s,x_m,y_m,z_m"
    assert write_uwb(tmp_path / "uwb2.csv", ranges).read_bytes() == p.read_bytes()
