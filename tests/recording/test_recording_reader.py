"""open_recording on the hand-made fleet in tests/data/broken/fleet.

Receiver tags (s after 2320:116400): u1 0.005 1.004 1.300(dup) 2.005 3.005; u2 -0.002 1.999 3.001;
base 0 1 2 3 4. uwb.csv and truth/u1.csv rows are listed in test_recording_csv.py.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from coplane.gtime import GpsTime
from coplane.recording.reader import FleetEpoch, open_recording

FLEET = Path(__file__).resolve().parents[1] / "data" / "broken" / "fleet"
T0 = GpsTime(2320, 116400.0)


def t(s: float) -> GpsTime:
    return GpsTime(2320, 116400.0 + s)


def test_fleet_epochs_group_by_nominal_time_and_keep_exact_tags() -> None:
    rec = open_recording(FLEET)
    fes = list(rec.fleet_epochs())
    assert [fe.time for fe in fes] == [t(0), t(1), t(2), t(3), t(4)]
    assert [fe.index for fe in fes] == [0, 1, 2, 3, 4]
    assert {k: v.time for k, v in fes[0].vehicles.items()} == {
        "u1": GpsTime(2320, 116400.005),
        "u2": t(-0.002),
    }
    assert set(fes[1].vehicles) == {"u1"}  # u2 has no epoch there: simply absent
    assert fes[1].vehicles["u1"].time == GpsTime(2320, 116401.004)  # the first of the two rounding to 1 s
    assert fes[2].vehicles["u2"].time == GpsTime(2320, 116401.999)
    assert fes[4].vehicles == {} and fes[4].base is not None  # only the base observed at 4 s
    assert all(fe.base is not None and fe.base.time == fe.time for fe in fes)


def test_uwb_rows_matched_within_a_tenth_of_the_interval() -> None:
    rec = open_recording(FLEET)
    by_t = {fe.time: [(u.time, u.pair, u.range_m) for u in fe.uwb] for fe in rec.fleet_epochs()}
    assert by_t == {
        t(0): [(t(0), ("u1", "u2"), 14.732)],  # the 0.02 s later reversed duplicate is dropped
        t(1): [],
        t(2): [(t(2), ("u1", "u2"), 14.9)],
        t(3): [(GpsTime(2320, 116403.04), ("u1", "u2"), 15.2)],
        t(4): [],
    }
    kinds = rec.problems.counts
    assert kinds["unmatched-row"] == 2  # 116401.5 (0.5 s off) and 116405 (no epoch there)
    assert kinds["duplicate-row"] == 2  # one exact-tag duplicate (reader) + one within an epoch
    assert kinds["duplicate-epoch"] == 1  # u1 at 1.300 s


def test_truth_at_nominal_times() -> None:
    rec = open_recording(FLEET)
    truth = rec.truth_at("u1")
    assert truth == {
        t(0): (-3817681.3807, 3562839.9785, 3650158.3760),
        t(1): (-3817681.3817, 3562839.9795, 3650158.3770),
        t(3): (-3817681.3847, 3562839.9835, 3650158.3810),
    }
    assert rec.truth_at("u2") == {} and rec.truth("u2") == []
    assert rec.problems.counts["unmatched-row"] == 1  # 116402.5, reported once for the file


def test_truth_at_an_epoch_is_the_nearest_row() -> None:
    """`Recording.truth_at` with a reference given later (`coplane eval --truth ID=FILE`): at the
    recording's rate, a second row in one epoch's reach is a fault, counted, and the nearer row
    is the truth; a reference ten times denser has such rows by nature, not counted."""
    from coplane.recording.model import TruthPoint

    def p(s: float, x: float) -> TruthPoint:
        return TruthPoint(t(s), (x, 3562839.0, 3650158.0))

    rec = open_recording(FLEET)
    rec.use_truth_points("u1", [p(0.0, 1.0), p(0.95, 2.0), p(1.02, 3.0), p(2.0, 4.0)], Path("ref.pos"))
    assert {k: v[0] for k, v in rec.truth_at("u1").items()} == {t(0): 1.0, t(1): 3.0, t(2): 4.0}
    assert rec.problems.counts["duplicate-row"] == 1
    dense = open_recording(FLEET)
    dense.use_truth_points("u1", [p(0.1 * k, float(k)) for k in range(31)], Path("ins.pos"))
    assert {k: v[0] for k, v in dense.truth_at("u1").items()} == {
        t(0): 0.0,
        t(1): 10.0,
        t(2): 20.0,
        t(3): 30.0,
    }
    assert dense.problems.counts["duplicate-row"] == 0 and dense.problems.counts["unmatched-row"] == 0


def test_everything_read_once_and_problems_counted_once() -> None:
    rec = open_recording(FLEET)
    assert rec.nav is rec.nav
    assert rec.nav.satellites == ["C01", "C14", "C59", "G05", "G06", "G13"]
    assert rec.vehicle_epochs("u1") is rec.vehicle_epochs("u1")
    list(rec.fleet_epochs())
    rec.truth_at("u1")
    first = dict(rec.problems.counts)
    list(rec.fleet_epochs())
    rec.truth_at("u1")
    assert dict(rec.problems.counts) == first
    assert len(rec.vehicle_epochs("u1")) == 4  # the duplicate-epoch is not returned
    assert [e.time for e in rec.base_epochs()] == [t(s) for s in range(5)]
    with pytest.raises(KeyError):
        rec.vehicle_epochs("nobody")


def test_fleet_epoch_is_frozen() -> None:
    fe = next(open_recording(FLEET).fleet_epochs())
    assert isinstance(fe, FleetEpoch)
    with pytest.raises(AttributeError):
        fe.index = 3  # type: ignore[misc]


def test_problems_beyond_those_kept_are_counted_by_kind_and_by_file() -> None:
    """Only the first `keep` are kept in full; the counts (what `recording show` prints per file) are whole."""
    from coplane.recording.problems import Problems

    p = Problems(keep=2)
    for k in range(5):
        p.add("a.obs", k + 1, "malformed-line", "bad")
    p.add("b.ubx", None, "garbled-frame", "1 byte(s) skipped", offset=7)
    assert len(p.items) == 2 and p.total == 6
    assert p.by_path == {"a.obs": 5, "b.ubx": 1} and p.counts == {"malformed-line": 5, "garbled-frame": 1}


def test_a_receiver_faster_than_the_interval_is_decimated_not_reported(tmp_path: Path) -> None:
    """A 1 s log in a 2 s recording (a 5 Hz one in a 1 s fleet alike): the epoch nearest each
    nominal time is kept, the others are counted as decimated, not as 'duplicate-epoch' problems
    (before, half of the log was reported as input problems and --strict failed)."""
    import dataclasses

    from coplane.recording.manifest import load_manifest, write_manifest
    from coplane.sim.generate import simulate

    path = simulate("open-sky", tmp_path / "sim", vehicles=1, duration_s=20.0, seed=1)
    write_manifest(dataclasses.replace(load_manifest(path), interval_s=2.0))
    u1 = load_manifest(path).vehicle("u1").obs
    assert open_recording(path).decimations()[u1][0] == 10  # read on asking, not only once loaded
    rec = open_recording(path)
    kept = rec.vehicle_epochs("u1")
    assert len(kept) == 10 and rec.problems.total == 0
    assert all(abs(e.time - rec.nominal(e.time)) < 0.1 for e in kept)
    skipped, own = rec.decimated[rec.manifest.vehicle("u1").obs]
    assert skipped == 10 and own == pytest.approx(1.0, abs=1e-3)  # the receiver's clock drifts
    from typer.testing import CliRunner

    from coplane.cli import app

    r = CliRunner().invoke(app, ["recording", "show", str(path)])
    said = " ".join(r.output.split())
    assert "DGNSS corrections exist only" not in said  # the faster base is decimated too
    assert r.exit_code == 0 and "logs every 1 s, decimated to the recording's 2 s (10 epochs" in said, (
        r.output
    )


def test_only_a_base_slower_than_the_interval_is_a_corrections_note() -> None:
    """A slower base leaves epochs without DGNSS corrections; a faster one is decimated like any
    receiver (`Recording._dedupe`), so saying its corrections exist only at its epochs misled."""
    from types import SimpleNamespace

    from coplane.recording.plan import coverage_notes

    def summary(interval: float) -> SimpleNamespace:
        return SimpleNamespace(interval_s=interval, doppler_share=1.0, first=None, last=None)

    def notes(base_interval: float) -> list[str]:
        summaries = {Path("u1.obs"): summary(1.0), Path("base.obs"): summary(base_interval)}
        return coverage_notes(summaries, {"u1": Path("u1.obs")}, Path("base.obs"), 1.0)  # type: ignore[arg-type]

    assert notes(5.0) == [
        "base logs every 5 s, the vehicles every 1 s: DGNSS corrections exist only at the base's epochs"
    ]
    assert notes(0.2) == [] and notes(1.0) == []
