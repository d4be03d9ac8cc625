"""The `coplane` command as a user runs it (typer's runner, real data and the bundled recording)."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from coplane.cli import app
from coplane.geo import geodetic_to_ecef

runner = CliRunner()


@pytest.mark.realdata
def test_spp_writes_rtklib_pos_and_prints_accuracy(real_data: Path, tmp_path: Path) -> None:
    out = tmp_path / "rover.pos"
    r = runner.invoke(
        app, ["spp", str(real_data / "matrtklib_nagoya_static_20240624"), "--dgnss", "--out", str(out)]
    )
    assert r.exit_code == 0, r.output
    assert "RMSE" in r.output and "rover" in r.output and "100.0" in r.output  # availability %
    rows = [ln.split() for ln in out.read_text().splitlines() if not ln.startswith("%")]
    assert len(rows) == 301  # every epoch has a fix in open sky
    assert {row[5] for row in rows} == {"4"}  # Q = 4: DGPS
    lat, lon, h = (float(x) for x in rows[0][2:5])
    truth = np.array(
        [
            float(x)
            for x in (real_data / "matrtklib_nagoya_static_20240624/rover_position.txt")
            .read_text()
            .split()[:3]
        ]
    )
    p = geodetic_to_ecef(np.radians(lat), np.radians(lon), h)
    q = geodetic_to_ecef(np.radians(truth[0]), np.radians(truth[1]), truth[2])
    assert np.linalg.norm(p - q) < 3.0


def test_spp_measured_against_its_own_pos_file_has_no_error(real_data: Path, tmp_path: Path) -> None:
    """`coplane spp --truth rover=FILE` with the .pos it wrote: RTKLIB's layout read back by
    `recording.trajectories` gives every fix back to the file's 0.1 mm, so the errors are zero."""
    nagoya = str(real_data / "matrtklib_nagoya_static_20240624")
    out = tmp_path / "rover.pos"
    assert runner.invoke(app, ["spp", nagoya, "--out", str(out)]).exit_code == 0
    r = runner.invoke(app, ["spp", nagoya, "--out", str(tmp_path / "again.pos"), "--truth", f"rover={out}"])
    assert r.exit_code == 0, r.output
    assert "rover: 301 points from an RTKLIB .pos file (single 301)" in " ".join(r.output.split())
    row = next(ln.split("│") for ln in r.output.splitlines() if "│ rover" in ln)
    assert [c.strip() for c in row[5:7]] == ["0.00", "0.00"], row  # H and V RMSE


def test_bad_arguments_give_a_clear_error(tmp_path: Path) -> None:
    r = runner.invoke(app, ["spp", str(tmp_path / "nope"), "--out", str(tmp_path / "x.pos")])
    assert r.exit_code == 2 and "error" in r.output
    r = runner.invoke(app, ["eval", "--methods", "pc,warp-drive", "--out", str(tmp_path)])
    assert r.exit_code == 2 and "warp-drive" in r.output and "valid methods" in r.output
    r = runner.invoke(app, ["eval", "--interruption", "150", "--out", str(tmp_path)])
    assert r.exit_code == 2 and "0..100" in r.output
    r = runner.invoke(app, ["eval", "--interruption", "10,abc", "--out", str(tmp_path)])
    assert r.exit_code == 2 and "--interruption '10,abc': 'abc' is not a number" in r.output, r.output
    r = runner.invoke(app, ["eval", "--fgo", "fde_k_long=-1", "--out", str(tmp_path)])
    assert r.exit_code == 2 and "fde_k_long must be finite and > 0" in r.output, r.output
    r = runner.invoke(app, ["eval", "--fgo", "warp=9", "--out", str(tmp_path)])
    assert r.exit_code == 2 and "no such factor-graph setting" in r.output, r.output
    r = runner.invoke(app, ["fleet", "--method", "warp-drive", "--no-api"])
    assert r.exit_code == 2 and "valid methods" in r.output
    r = runner.invoke(app, ["fleet", str(tmp_path / "nope"), "--no-api"])
    assert r.exit_code == 2 and "error" in r.output and "nope" in r.output
    r = runner.invoke(app, ["fleet", "--pace", "warp", "--no-api"])
    assert r.exit_code == 2 and "'warp' is not one of 'lockstep'," in r.output
    for args, said in (
        (["--speed", "0", "--pace", "realtime"], "--speed must be a finite factor > 0"),
        (["--interruption", "150"], "--interruption must be within 0..100 %, got 150"),
        (["--port", "70000"], "--port must be within 0..65535, got 70000"),
        (["--api-port", "-3"], "--api-port must be within 1..65535, got -3"),
        (["--format", "pos,kml", "--out", str(tmp_path)], "unknown --format kml (expected tum, pos)"),
        (["--format", "pos"], "--format writes its files into --out: give --out DIR"),
    ):
        r = runner.invoke(app, ["fleet", "--no-api", "--insecure", *args])
        assert r.exit_code == 2 and said in " ".join(r.output.split()), r.output
    # code that makes the options itself meets the same checks (typer stops a bad pace before)
    from coplane.errors import ConfigError
    from coplane.fleet.run import FleetOptions

    with pytest.raises(ConfigError, match="--pace must be lockstep or realtime, got 'warp'"):
        FleetOptions(recording=tmp_path, pace="warp")
    # a path the OS refuses is named with the reason, without a traceback
    (tmp_path / "afile").write_text("")
    r = runner.invoke(app, ["simulate", "--out", str(tmp_path / "afile" / "rec"), "--duration", "1"])
    said = "".join(r.output.split())  # rich folds a long path anywhere
    assert r.exit_code == 2 and f"error:{tmp_path / 'afile'}" in said and "Notadirectory" in said, r.output
    assert "Traceback" not in r.output


def test_eval_writes_tables_figures_and_solution_csvs(tmp_path: Path) -> None:
    from coplane.sim.generate import simulate

    rec = simulate("urban-loop", tmp_path / "rec", vehicles=3, duration_s=30, seed=5)
    out = tmp_path / "eval"
    r = runner.invoke(
        app, ["eval", str(rec), "--methods", "non-cp,pc", "--interruption", "0,50", "--out", str(out)]
    )
    assert r.exit_code == 0, r.output
    assert "epoch/s" not in r.output  # no progress bars redrawn into what is not a terminal
    assert (out / "accuracy.md").read_text().count("| pc") >= 3
    by_env = (out / "accuracy_by_environment.md").read_text()  # pooled, per simulated road section
    assert "| pc@r50 |" in by_env and "open (" in by_env and "H p50 / p99 / max" in by_env
    for label in ("non-cp", "pc", "pc@r50"):
        csvs = sorted((out / "solutions" / label).glob("*.csv"))
        assert [c.stem for c in csvs] == ["u1", "u2", "u3"]
        header = csvs[0].read_text().splitlines()[0]
        assert header.startswith("gps_week,tow_s,x_m,y_m,z_m")
    assert (out / "solutions" / "non-cp@r50").exists() is False  # no ranging: no interruption runs
    # per epoch, how good and why: local sigmas, satellites used and kept, ranges, the plane
    rows = []
    for vid in ("u1", "u2", "u3"):
        with (out / "solutions" / "pc" / f"{vid}.csv").open() as fh:
            rows += list(csv.DictReader(fh))
    assert len(rows) == 90
    for row in rows:
        assert 0.0 < float(row["sigma_h_m"]) < 50.0 and 0.0 < float(row["sigma_v_m"]) < 50.0
        assert 0 <= int(row["n_pseudoranges"]) <= int(row["n_satellites"]) and row["gnss_fix"] in ("0", "1")
        # the satellites left out, by name: as many as the node used and the estimator did not
        excluded = row["excluded"].split()
        assert len(excluded) == int(row["n_satellites"]) - int(row["n_pseudoranges"])
        assert excluded == sorted(excluded)
        assert row["vdop"] == "" or float(row["vdop"]) > 0.0  # empty where the agent had no fix
        assert int(row["n_ranges"]) >= 0
        assert row["plane"] == "used" or row["plane"].startswith(("unavailable: ", "available"))
        assert row["plane_source"] in ("fleet", "") and (
            row["plane"] != "used" or row["plane_source"] == "fleet"
        )
    assert any(int(row["n_ranges"]) > 0 for row in rows)
    assert any(row["vdop"] for row in rows) and {row["raim_excluded"] for row in rows} != {""}
    # and over the drive: the satellites each method left out most, per vehicle (exclusions.md)
    table = (out / "exclusions.md").read_text().splitlines()
    pc_u1 = next(ln for ln in table if ln.startswith("| pc | u1 |")).split("|")
    left_out = sum(len(row["excluded"].split()) for row in rows[:30])  # u1's rows come first
    assert int(pc_u1[3]) == 30 and int(pc_u1[5]) == left_out, (pc_u1, left_out)
    assert any(row["plane"] == "used" for row in rows), {row["plane"] for row in rows}
    pngs = {p.name for p in out.glob("*.png")}
    assert {
        "cdf_h_u1.png",
        "cdf_v_u1.png",
        "error_time_u1.png",
        "rmse_vs_interruption_u1.png",
        "plane_map.png",
    } <= pngs


def test_eval_of_a_drive_without_truth_says_so(real_data: Path, tmp_path: Path) -> None:
    """No empty accuracy table: which vehicle has no truth, and the way to one (the base's RTK)."""
    rec = real_data / "hk_klt_20210610_f9p_rover_hksc_base"
    r = runner.invoke(app, ["eval", str(rec), "--methods", "non-cp", "--out", str(tmp_path)])
    assert r.exit_code == 0, r.output
    assert "no truth for klt1" in r.output and "--truth rtk" in r.output
    assert "H RMSE" not in r.output
    assert (tmp_path / "solutions" / "non-cp" / "klt1.csv").exists()


def test_eval_formats_and_map_methods_need_a_map(tmp_path: Path) -> None:
    """`--format tum,pos` writes evo's files for every run and the truth, and RTKLIB .pos files
    with the CSV's positions; a map method without --map is refused with a message that says how
    to make a map."""
    from coplane.recording.problems import Problems
    from coplane.recording.trajectories import Q_DGPS, read_pos
    from coplane.sim.generate import simulate

    rec = simulate("urban-loop", tmp_path / "rec", vehicles=2, duration_s=10, seed=5)
    out = tmp_path / "eval"
    args = ["eval", str(rec), "--methods", "non-cp", "--format", "tum,pos", "--out", str(out)]
    r = runner.invoke(app, args)
    assert r.exit_code == 0, r.output
    assert sorted(p.name for p in (out / "solutions" / "non-cp").glob("*.tum")) == ["u1.tum", "u2.tum"]
    assert sorted(p.name for p in (out / "truth").glob("*.tum")) == ["u1.tum", "u2.tum"]
    pos = read_pos(out / "solutions" / "non-cp" / "u1.pos", Problems())
    with (out / "solutions" / "non-cp" / "u1.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert len(pos) == len(rows) == 10
    np.testing.assert_allclose(
        [p.ecef for p in pos], [[float(x[k]) for k in ("x_m", "y_m", "z_m")] for x in rows], atol=1e-3
    )
    assert {p.quality for p in pos} == {Q_DGPS}  # the simulated drive has a base: DGNSS fixes
    assert [p.n_sats for p in pos] == [int(x["n_pseudoranges"]) for x in rows]
    r = runner.invoke(app, ["eval", str(rec), "--methods", "non-cp", "--format", "kml", "--out", str(out)])
    assert r.exit_code != 0 and "kml" in r.output
    r = runner.invoke(app, ["eval", str(rec), "--methods", "pc-map", "--out", str(out)])
    assert r.exit_code == 2 and "--map" in r.output and "coplane map build" in r.output, r.output
    # an opt-in setting changed from the command line is said on the console and in accuracy.json
    r = runner.invoke(
        app, ["eval", str(rec), "--methods", "non-cp", "--fgo", "fde_k_long=2.5", "--out", str(out)]
    )
    assert r.exit_code == 0, r.output
    assert "settings changed for every FGO method: fde_k_long=2.5" in r.output
    assert "fde_k_long=2.5" in (out / "accuracy.json").read_text()


def test_eval_reports_the_recordings_input_problems(tmp_path: Path) -> None:
    """UWB rows with NaN, negative or absurd ranges are dropped by the reader and counted in eval's
    output (they used to vanish silently); the run itself goes on with the valid rows."""
    from coplane.sim.generate import simulate

    rec = simulate("urban-loop", tmp_path / "rec", vehicles=2, duration_s=10, seed=5)
    uwb = rec / "uwb.csv"
    lines = uwb.read_text().splitlines()
    week, tow = lines[1].split(",")[:2]
    bad = [f"{week},{tow},u1,u2,{r}" for r in ("nan", "-3.0", "1e308")]
    uwb.write_text("\n".join([*lines, *bad]) + "\n")
    r = runner.invoke(app, ["eval", str(rec), "--methods", "mci", "--out", str(tmp_path / "eval")])
    assert r.exit_code == 0, r.output
    assert "3 input problems" in r.output, r.output


def test_fleet_prints_the_input_problems_and_fails_strict(monkeypatch: pytest.MonkeyPatch) -> None:
    """`coplane fleet` reports the recording's problem count as eval and spp do, and `--strict`
    turns a recording that positioned nothing into exit code 3 (the replay itself is stubbed)."""
    import coplane.fleet as fleet_pkg
    from coplane.evaluate.runner import MethodRun
    from coplane.fleet import FleetResult
    from coplane.recording.health import InputHealth

    def fake_run(*args: object, **kwargs: object) -> FleetResult:
        return FleetResult(
            recording_name="r",
            method="pc",
            vehicles=["u1"],
            truth_vehicles=[],
            run=MethodRun("pc", 0.0),
            stats={},
            diagnostics=None,
            failed_agents={},
            n_epochs=0,
            input_problems={"epoch-time-jump": 2, "uwb-range": 1},
            input_health=InputHealth(records=10, problems=3),
        )

    monkeypatch.setattr(fleet_pkg, "run_fleet", fake_run)
    r = runner.invoke(app, ["fleet", "--no-api", "--insecure"])
    assert r.exit_code == 0, r.output
    assert "3 input problems" in r.output and "epoch-time-jump x2" in r.output, r.output
    r = runner.invoke(app, ["fleet", "--no-api", "--insecure", "--strict"])
    assert r.exit_code == 3, r.output


def test_progress_bars_on_a_terminal_only(monkeypatch: pytest.MonkeyPatch) -> None:
    import io

    from coplane.cli.options import progress_bars

    class Tty(io.StringIO):
        def isatty(self) -> bool:
            return True

    monkeypatch.setattr("sys.stderr", io.StringIO())
    assert not progress_bars()
    monkeypatch.setattr("sys.stderr", Tty())
    assert progress_bars()


def test_service_options_are_checked_before_anything_starts(tmp_path: Path) -> None:
    """A pace or a method that no service takes stops `compose` before it writes a file that
    would fail at start-up; a setting a service's pydantic settings refuse is named by its field,
    without a traceback."""
    out = tmp_path / "compose.yml"
    for args, said in (
        (["--pace", "fast"], "'fast' is not one of 'lockstep',"),
        (["--method", "warp"], "unknown method 'warp'"),
    ):
        r = runner.invoke(app, ["compose", "--out", str(out), *args])
        assert r.exit_code == 2 and said in " ".join(r.output.split()), r.output
        assert not out.exists()
    r = runner.invoke(
        app,
        ["agent", "--vehicle-id", "u1", "--insecure", "--max-correction-age", "-5", "--recording", "nowhere"],
    )
    said = " ".join(r.output.split())
    assert r.exit_code == 2 and "AgentSettings: max_correction_age_s: Input should be greater than 0" in said
    assert "Traceback" not in r.output


def test_eval_refuses_an_unknown_vehicle_and_no_method_and_runs_a_repeated_one_once(tmp_path: Path) -> None:
    """`--vehicle u9` used to give empty tables and no figures silently, `--methods ''` empty
    outputs, and a method named twice ran twice."""
    from coplane.sim.generate import simulate

    rec = simulate("urban-loop", tmp_path / "rec", vehicles=2, duration_s=5, seed=5)
    out = tmp_path / "eval"
    r = runner.invoke(app, ["eval", str(rec), "--methods", "non-cp", "--vehicle", "u9", "--out", str(out)])
    assert r.exit_code == 2 and "vehicle 'u9' is not in recording" in r.output and "u1, u2" in r.output
    r = runner.invoke(app, ["eval", str(rec), "--methods", " , ", "--out", str(out)])
    assert r.exit_code == 2 and "no method to run" in r.output
    assert not out.exists()
    r = runner.invoke(app, ["eval", str(rec), "--methods", "non-cp,non-cp", "--out", str(out)])
    assert r.exit_code == 0 and r.output.count("non-cp: 5 epochs in") == 1, r.output


def test_fleet_message_counts_name_every_bucket_that_holds_messages() -> None:
    """A lockstep re-send made 'u1: used 600/601, late 0, rejected 0' with the 601st nowhere."""
    from coplane.cli.fleet import message_counts
    from coplane.messages import DiagnosticsMessage, VehicleCounters

    diag = DiagnosticsMessage(
        fleet="f",
        method="pc",
        pace="lockstep",
        epochs_solved=600,
        vehicles={
            "u1": VehicleCounters(received=601, used=600, duplicate=1),
            "u2": VehicleCounters(received=600, used=600),
        },
    )
    assert message_counts(diag) == (
        "messages: u1: used 600/601, late 0, rejected 0, duplicate 1; u2: used 600/600, late 0, rejected 0"
    )


def test_the_command_line_starts_without_pydantic() -> None:
    """The options' types (`coplane.typing.Pace`) and the settings-error handler must not pull
    pydantic (and the bus messages) into every command's start: they load where a command uses
    them."""
    from support.fresh_python import fresh_python

    code = "import sys, coplane.cli; print('pydantic' in sys.modules, 'coplane.messages' in sys.modules)"
    out = fresh_python(code)
    assert out.split() == ["False", "False"], out
