"""What accuracy is measured against (`evaluate.truth`): `--truth recording | rtk | ID=FILE` of
`coplane eval` and `coplane fleet`. A reference trajectory from another tool (here an RTKLIB .pos
written from the simulator's truth) replaces the named vehicle's truth; bad rows are counted, and
a file that gives nothing stops the run before any method runs."""

from __future__ import annotations

import itertools
import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from coplane.cli import app
from coplane.errors import ConfigError
from coplane.evaluate.evaluation import evaluate
from coplane.evaluate.truth import TruthChoice, apply_truth, parse_truth_choice
from coplane.fleet import FleetOptions, run_fleet
from coplane.geo import ecef_to_geodetic, enu_rotation
from coplane.recording.reader import open_recording
from coplane.sim.generate import simulate

runner = CliRunner()
XYZ_HEADER = "%  GPST                  x-ecef(m)      y-ecef(m)      z-ecef(m)   Q  ns"


@pytest.fixture(scope="module")
def sim(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return simulate("urban-loop", tmp_path_factory.mktemp("truth") / "sim", vehicles=2, duration_s=12, seed=5)


def _pos_file(path: Path, sim: Path, vid: str, up_m: float = 0.0, garbage: bool = False) -> Path:
    """`vid`'s truth as an RTKLIB .pos (ECEF, week and seconds, all fixed), moved `up_m` up."""
    lines = [XYZ_HEADER]
    for p in open_recording(sim).truth(vid):
        lat, lon, _ = ecef_to_geodetic(np.asarray(p.ecef_m))
        x, y, z = np.asarray(p.ecef_m) + up_m * enu_rotation(lat, lon)[2]
        lines.append(f"{p.time.week} {p.time.tow:10.3f} {x:14.4f} {y:14.4f} {z:14.4f} 1 12")
        if garbage and len(lines) == 4:
            lines.append(f"{p.time.week} not-a-time 1 2 3 1 12")
    path.write_text("\n".join(lines) + "\n")
    return path


def test_truth_options_parse_into_one_source_and_references() -> None:
    assert parse_truth_choice(None) == TruthChoice("recording", ())
    assert parse_truth_choice(["rtk", "u1=a.pos", "u2=b.txt"]) == TruthChoice(
        "rtk", (("u1", Path("a.pos")), ("u2", Path("b.txt")))
    )
    ((_, point),) = parse_truth_choice(["u1=35.0,137.0,50.0"]).references  # lat, lon, h
    assert isinstance(point, tuple) and abs(float(np.linalg.norm(point)) - 6371e3) < 30e3
    for bad, match in (
        (["rtk", "recording"], "one source for every vehicle"),
        (["u1=a.pos", "u1=b.pos"], "'u1' given twice"),
        (["=a.pos"], "expected recording, rtk, ID=FILE or ID=x,y,z"),
        (["RTK"], "must be one of recording, rtk"),
    ):
        with pytest.raises(ConfigError, match=match):
            parse_truth_choice(bad)


def test_a_reference_file_replaces_one_vehicles_truth(sim: Path, tmp_path: Path) -> None:
    """The same positions as a .pos give the recording's errors (to the file's 0.1 mm); moved 2 m
    up, the vertical bias moves by -2 m; the other vehicle keeps the recording's truth."""
    own = evaluate(open_recording(sim), ["non-cp"]).stats["non-cp"]
    same = _pos_file(tmp_path / "same.pos", sim, "u1", garbage=True)
    rec = open_recording(sim)
    ev = evaluate(rec, ["non-cp"], truth=TruthChoice(references=(("u1", same),)))
    got = ev.stats["non-cp"]
    assert got["u1"].n_truth == own["u1"].n_truth and got["u1"].h_rmse_m == pytest.approx(
        own["u1"].h_rmse_m, abs=1e-4
    )
    assert got["u2"] == own["u2"]
    note = ev.notes["truth"]
    assert (
        "u1: 12 points from an RTKLIB .pos file (fix 12) (same.pos, 1 bad rows skipped), at 12 of its 12 epochs"
        in note
    ), note
    assert rec.problems.total == 1 and "same.pos:5" in str(rec.problems.items[0])

    up = _pos_file(tmp_path / "up.pos", sim, "u1", up_m=2.0)
    moved = evaluate(open_recording(sim), ["non-cp"], truth=TruthChoice(references=(("u1", up),))).stats[
        "non-cp"
    ]
    assert moved["u1"].v_bias_m == pytest.approx(own["u1"].v_bias_m - 2.0, abs=1e-3)


def test_a_reference_of_another_week_is_said_to_cover_nothing(sim: Path, tmp_path: Path) -> None:
    """A reference a week off (another drive's file) leaves every error blank: the note says it
    covers none of the vehicle's epochs and gives both spans, so the empty table is explained."""
    same = _pos_file(tmp_path / "same.pos", sim, "u1").read_text().splitlines()
    shifted = [same[0]] + [f"{int(r.split()[0]) + 1} {r.split(' ', 1)[1]}" for r in same[1:]]
    later = tmp_path / "later.pos"
    later.write_text("\n".join(shifted) + "\n")
    ev = evaluate(open_recording(sim), ["non-cp"], truth=TruthChoice(references=(("u1", later),)))
    note = " ".join(ev.notes["truth"].split())
    assert "(later.pos), at 0 of its 12 epochs: the reference is from " in note, note
    assert ev.stats["non-cp"]["u1"].n_solved == 0  # no epoch with both: the blank row the note explains


def test_a_reference_that_gives_nothing_stops_before_any_method(sim: Path, tmp_path: Path) -> None:
    rec = open_recording(sim)
    empty = tmp_path / "empty.pos"
    empty.write_text(XYZ_HEADER + "\n2300 junk 1 2 3 1 12\n")
    for choice, match in (
        (TruthChoice(references=(("u9", empty),)), "--truth u9=.*no such vehicle"),
        (TruthChoice(references=(("u9", (1.0, 2.0, 3.0)),)), "--truth u9: no such vehicle"),
        (
            TruthChoice(references=(("u1", empty),)),
            "--truth u1=.*empty.pos: no usable point \\(1 bad rows, the first: .*empty.pos:2",
        ),
        (TruthChoice(references=(("u1", tmp_path / "missing.pos"),)), "missing.pos: cannot read"),
        (TruthChoice(references=(("u1", sim / "fleet.toml"),)), "not a trajectory coplane reads"),
    ):
        with pytest.raises(ConfigError, match=match):
            apply_truth(rec, choice)
    # the fleet refuses it before a process starts
    with pytest.raises(ConfigError, match="no usable point"):
        run_fleet(
            FleetOptions(
                recording=sim, api=False, insecure=True, truth=TruthChoice(references=(("u1", empty),))
            )
        )


def test_eval_takes_reference_files_on_the_command_line(sim: Path, tmp_path: Path) -> None:
    up = _pos_file(tmp_path / "up.pos", sim, "u2", up_m=2.0)
    out = tmp_path / "out"
    r = runner.invoke(
        app, ["eval", str(sim), "--methods", "non-cp", "--truth", f"u2={up}", "--out", str(out)]
    )
    assert r.exit_code == 0, r.output
    assert "references: u2: 12 points from an RTKLIB .pos file" in " ".join(r.output.split())
    acc = json.loads((out / "accuracy.json").read_text())
    assert acc
    bad = runner.invoke(app, ["eval", str(sim), "--methods", "non-cp", "--truth", "u2", "--out", str(out)])
    assert bad.exit_code != 0 and "must be one of recording, rtk" in " ".join(bad.output.split())
    # two numbers are a mistyped point, not a file name to look for
    bad = runner.invoke(
        app, ["eval", str(sim), "--methods", "non-cp", "--truth", "u2=1,2", "--out", str(out)]
    )
    said = " ".join(bad.output.split())
    assert bad.exit_code == 2 and "a surveyed point is three numbers, x,y,z (m) or lat,lon,h; got 2" in said


@pytest.mark.slow
def test_the_fleet_and_its_api_measure_against_a_reference_file(sim: Path, tmp_path: Path) -> None:
    """`coplane fleet --truth u1=FILE`: the table and the API (handed the file's points) give the
    numbers `coplane eval` gives against the same file."""
    import httpx

    from coplane.fleet.launcher import free_port

    up = _pos_file(tmp_path / "up.pos", sim, "u1", up_m=2.0)
    choice = TruthChoice(references=(("u1", up),))
    port, seen = free_port(), []
    res = run_fleet(
        FleetOptions(
            recording=sim,
            method="non-cp",
            api_port=port,
            certs=tmp_path / "certs",
            map=Path("none"),
            port=0,
            truth=choice,
            out=tmp_path / "out",
        ),
        serve=lambda _: seen.extend(
            httpx.get(f"http://127.0.0.1:{port}/accuracy", timeout=10).json()["entries"]
        ),
    )
    assert "references: u1:" in res.truth_note
    ref = evaluate(open_recording(sim), ["non-cp"], truth=choice).stats["non-cp"]["u1"]
    st = res.stats["u1"]
    assert (st.n_truth, st.h_rmse_m, st.v_bias_m) == (ref.n_truth, ref.h_rmse_m, ref.v_bias_m)
    api = next(e for e in seen if e["vehicle_id"] == "u1")
    assert api["v_bias_m"] == pytest.approx(st.v_bias_m, abs=1e-4)
    # --out: the solution CSVs and exclusions.md, as `coplane eval` writes them
    assert (tmp_path / "out" / "solutions" / "non-cp" / "u1.csv").is_file()
    assert (tmp_path / "out" / "exclusions.md").read_text().splitlines()[2].startswith("| non-cp | u1 | 12 |")


@pytest.mark.realdata
def test_a_surveyed_point_is_the_truth_of_a_static_receiver(real_data: Path) -> None:
    """`--truth ID=lat,lon,h` on a real static set: Nagoya's rover at its published position
    gives the recording's own truth (made from the same point) to the millimetre."""
    nagoya = real_data / "matrtklib_nagoya_static_20240624"
    own = evaluate(open_recording(nagoya), ["non-cp"]).stats["non-cp"]["rover"]
    choice = parse_truth_choice(["rover=35.13469901,136.97757549,104.8626"])
    rec = open_recording(nagoya)
    ev = evaluate(rec, ["non-cp"], truth=choice)
    got = ev.stats["non-cp"]["rover"]
    assert (
        got.n_truth == own.n_truth == 301 and "rover: a surveyed point at its 301 epochs" in ev.notes["truth"]
    )
    assert got.h_rmse_m == pytest.approx(own.h_rmse_m, abs=1e-3) and got.v_rmse_m == pytest.approx(
        own.v_rmse_m, abs=1e-3
    )


def test_a_reference_at_twenty_times_the_rate_is_taken_at_each_epoch(sim: Path, tmp_path: Path) -> None:
    """An INS-like reference at 20 Hz against the 1 Hz recording: each epoch's truth is the row
    at it, not the first row within 0.1 s (one 0.05 s early, a metre at road speed), and the rows
    between the epochs are not problems. The errors are the recording's own."""
    rows = open_recording(sim).truth("u1")
    lines = [XYZ_HEADER]
    for a, b in itertools.pairwise(rows):
        pa, pb = np.asarray(a.ecef_m), np.asarray(b.ecef_m)
        for k in range(20):
            x, y, z = pa + (pb - pa) * k / 20.0
            t = a.time + 0.05 * k
            lines.append(f"{t.week} {t.tow:10.3f} {x:14.4f} {y:14.4f} {z:14.4f} 1 12")
    last = rows[-1]
    lines.append(
        f"{last.time.week} {last.time.tow:10.3f} {last.ecef_m[0]:14.4f} {last.ecef_m[1]:14.4f} {last.ecef_m[2]:14.4f} 1 12"
    )
    dense = tmp_path / "ins20hz.pos"
    dense.write_text("\n".join(lines) + "\n")
    own = evaluate(open_recording(sim), ["non-cp"]).stats["non-cp"]["u1"]
    rec = open_recording(sim)
    got = evaluate(rec, ["non-cp"], truth=TruthChoice(references=(("u1", dense),))).stats["non-cp"]["u1"]
    assert got.n_truth == own.n_truth == 12
    assert got.h_rmse_m == pytest.approx(own.h_rmse_m, abs=1e-4) and got.v_bias_m == pytest.approx(
        own.v_bias_m, abs=1e-4
    )
    assert rec.problems.total == 0, dict(rec.problems.counts)
