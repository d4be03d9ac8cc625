"""`coplane recording init`: fleet.toml for a folder of RINEX files or receiver logs, checked on the real sets.

The sets of ../shared/data/real that come with a hand-written fleet.toml are copied without it:
the planned manifest must name the same files, interval and base position. The GEONET pair, which
has none, is then solved end to end against RTKLIB on the same files. UBX and RTCM 3 logs are
checked on `coplane convert`'s copies of a simulated one.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from coplane.cli import app
from coplane.errors import ConfigError
from coplane.evaluate.evaluation import evaluate
from coplane.recording.convert import convert_recording
from coplane.recording.discover import sniff, summarise_obs, vehicle_ids
from coplane.recording.manifest import load_manifest
from coplane.recording.plan import plan_recording, write_plan
from coplane.recording.positions import parse_position
from coplane.recording.problems import RecordingError
from coplane.recording.reader import open_recording
from coplane.sim.generate import bundled_default_path, simulate

runner = CliRunner()
DEFAULT_RECORDING_DIR = bundled_default_path()
GEONET = "rtklib_geonet_0759_3040_20050402"
# RTKLIB's test reference for 3040 (its makefile's base) and its kinematic RTK of 0759 against it
BASE_3040 = "-3978241.958,3382840.234,3649900.853"
POINT_0759 = "-3976219.188,3382371.604,3652511.141"


def _copy(real_data: Path, name: str, tmp_path: Path) -> Path:
    """A set's RINEX files without its fleet.toml and truth: what a user's folder holds."""
    out = tmp_path / name
    shutil.copytree(real_data / name, out, ignore=shutil.ignore_patterns("fleet.toml", "truth"))
    return out


def test_sniff_tells_observation_from_navigation_files(real_data: Path, tmp_path: Path) -> None:
    tst = real_data / "urbannav_hk_tst_20200603_static_f9p"
    kinds = {
        real_data / GEONET / "07590920.05o": ("obs", "G"),
        real_data / GEONET / "07590920.05n": ("nav", "G"),  # RINEX 2 "N": GPS
        tst / "hksc155c.20b": ("nav", "C"),
        tst / "hksc155c.20g": ("nav", "R"),
        real_data / "matrtklib_nagoya_static_20240624" / "base.nav": ("nav", "M"),
    }
    for path, (kind, system) in kinds.items():
        r = sniff(path)
        assert r is not None and (r.kind, r.system) == (kind, system), path
    (tmp_path / "notes.txt").write_text("not RINEX\n")
    assert sniff(tmp_path / "notes.txt") is None
    assert sniff(tmp_path / "missing") is None


@pytest.mark.parametrize(
    ("name", "options"),
    [
        ("urbannav_hk_tst_20200603_static_f9p", {}),
        (
            "matrtklib_nagoya_static_20240624",
            {"base": Path("base.obs"), "base_position": "35.134707705,136.977577939,104.853"},
        ),
        ("hk_klt_20210610_f9p_rover_hksc_base", {"base": Path("hksc1610.obs"), "base_position": "header"}),
    ],
)
def test_plan_matches_the_hand_written_manifest(
    real_data: Path, tmp_path: Path, name: str, options: dict
) -> None:
    """Same observation and navigation files, interval and base (Nagoya's base given as lat, lon,
    h from base_position.txt; KLT's header position, which is the published HKSC coordinate)."""
    if "base_position" in options:
        options = {**options, "base_position": parse_position(options["base_position"])}
    plan = plan_recording(_copy(real_data, name, tmp_path), **options)
    m, ref = plan.manifest, load_manifest(real_data / name)
    assert sorted(p.name for p in m.nav_files) == sorted(p.name for p in ref.nav_files)
    assert m.interval_s == ref.interval_s
    assert [v.obs.name for v in m.vehicles] == [v.obs.name for v in ref.vehicles]
    assert (m.base is None) == (ref.base is None)
    if m.base is not None and ref.base is not None:
        assert m.base.obs.name == ref.base.obs.name
        # KLT: the header's marker plus its antenna delta, within centimetres of the coordinate
        tol = 1e-3 if name.startswith("matrtklib") else 0.05
        assert np.allclose(m.base.position_ecef_m, ref.base.position_ecef_m, atol=tol)
    if name.startswith("urbannav"):  # GLONASS and Galileo navigation found and named as unused
        assert len(plan.skipped) == 4 and all("coplane uses GPS and BeiDou" in s for s in plan.skipped)


def test_geonet_pair_end_to_end_against_rtklib(real_data: Path, tmp_path: Path) -> None:
    """RINEX 2.10, GPS only, 30 s, no fleet.toml: `coplane recording init` with the base and the
    rover's surveyed point, then DGNSS `non-cp` against RTKLIB's DGPS on the same files."""
    rec = _copy(real_data, GEONET, tmp_path)
    r = runner.invoke(
        app,
        ["recording", "init", str(rec), "--base", "30400920.05o", f"--base-position={BASE_3040}",
         f"--truth=0759={POINT_0759}"],
    )  # fmt: skip
    assert r.exit_code == 0, r.output
    assert "Doppler on 0 %" in r.output and "wrote" in r.output
    assert "antenna taken 1.5 m above the road" in r.output  # the default, said
    recording = open_recording(rec)
    assert [v.id for v in recording.manifest.vehicles] == ["0759"] and recording.manifest.interval_s == 30.0
    assert len(recording.truth_at("0759")) == 120
    ev = evaluate(recording, ["non-cp", "rtklib"], [0.0], None)
    ours, rtklib = ev.stats["non-cp"]["0759"], ev.stats["rtklib"]["0759"]
    assert ours.availability == 1.0 and rtklib.availability == 1.0
    # both about 0.4 m H and 0.6 m V over the 3.3 km baseline (2026-11-30: 0.39 / 0.56 and 0.38 / 0.59)
    assert ours.h_rmse_m < 0.6 and ours.v_rmse_m < 0.8
    assert abs(ours.h_rmse_m - rtklib.h_rmse_m) < 0.1 and abs(ours.v_rmse_m - rtklib.v_rmse_m) < 0.15
    # a second init does not overwrite the user's manifest
    again = runner.invoke(app, ["recording", "init", str(rec)])
    assert again.exit_code == 2 and "exists; --force replaces it" in again.output


def test_dry_run_prints_the_manifest_and_writes_nothing(real_data: Path, tmp_path: Path) -> None:
    rec = _copy(real_data, "urbannav_hk_tst_20200603_static_f9p", tmp_path)
    r = runner.invoke(app, ["recording", "init", str(rec), "--dry-run", "--antenna-height", "1.2"])
    assert r.exit_code == 0, r.output
    assert 'format = "fleet-recording/1"' in r.output and "antenna_height_m = 1.2" in r.output
    assert "antenna taken" not in r.output  # given, so nothing to say
    assert not (rec / "fleet.toml").exists()


def test_bad_requests_name_what_is_wrong(real_data: Path, tmp_path: Path) -> None:
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(RecordingError, match=r"no observation file \(RINEX, UBX or RTCM 3\) below it$"):
        plan_recording(empty)
    obs_only = tmp_path / "obs_only"
    obs_only.mkdir()
    shutil.copy(real_data / GEONET / "07590920.05o", obs_only)
    with pytest.raises(RecordingError, match="no GPS or BeiDou navigation file"):
        plan_recording(obs_only)
    # what is there instead of observations: a phone's log by its kind, other files by name
    phone = tmp_path / "phone"
    shutil.copytree(real_data / "gsdc2022_pixel_sample_csv", phone)
    with pytest.raises(RecordingError, match=r"device_gnss.csv is an Android GNSS measurement log"):
        plan_recording(phone)
    (empty / "notes.txt").write_text("hello\n")
    with pytest.raises(RecordingError, match=r"found notes.txt: none is RINEX"):
        plan_recording(empty)
    nav_only = tmp_path / "nav_only"
    nav_only.mkdir()
    shutil.copy(real_data / GEONET / "07590920.05n", nav_only)
    with pytest.raises(RecordingError, match=r"no observation file \(RINEX, UBX or RTCM 3\) below it$"):
        plan_recording(nav_only)
    shutil.copy(real_data / GEONET / "30400920.05o", nav_only)
    with pytest.raises(RecordingError, match=r"no observation file .* for a vehicle"):  # the base's only
        plan_recording(nav_only, base=Path("30400920.05o"), base_position=parse_position(BASE_3040))
    rec = _copy(real_data, GEONET, tmp_path)
    with pytest.raises(ConfigError, match="--base needs --base-position"):
        plan_recording(rec, base=Path("30400920.05o"))
    with pytest.raises(ConfigError, match="without --base"):
        plan_recording(rec, base_position=parse_position(BASE_3040))
    with pytest.raises(ConfigError, match="no such file"):
        plan_recording(rec, base=Path("nope.obs"), base_position="header")
    outside = tmp_path / "elsewhere.obs"
    shutil.copy(real_data / GEONET / "30400920.05o", outside)
    with pytest.raises(ConfigError, match="outside"):
        plan_recording(rec, base=outside, base_position="header")
    with pytest.raises(ConfigError, match="--truth u9: no such vehicle"):
        plan_recording(rec, truth={"u9": (1.0, 2.0, 3.0)})
    with pytest.raises(ConfigError, match="invalid id"):
        plan_recording(rec, vehicles={"bad id": Path("07590920.05o")})
    with pytest.raises(ConfigError, match="named twice"):
        plan_recording(rec, vehicles={"a": Path("07590920.05o"), "b": Path("07590920.05o")})
    with pytest.raises(ConfigError, match="or is the base"):
        plan_recording(
            rec, vehicles={"a": Path("30400920.05o")}, base=Path("30400920.05o"), base_position="header"
        )
    # receivers at 30 s and 1 s in one folder: the fleet's interval is the user's to give
    shutil.copy(real_data / "urbannav_hk_tst_20200603_static_f9p" / "2020_06_03_TST_03.obs", rec)
    with pytest.raises(ConfigError, match=r"different intervals.*--interval 30, decimates"):
        plan_recording(rec)
    assert plan_recording(rec, interval_s=30.0).manifest.interval_s == 30.0
    # a file found that cannot be read is skipped with its reason, not the end of the plan; the
    # same file named by the user is an error
    (rec / "2020_06_03_TST_03.obs").unlink()
    (rec / "damaged.obs").write_text(
        "     3.03           OBSERVATION DATA    M: Mixed            RINEX VERSION / TYPE\n"
    )
    plan = plan_recording(rec)
    assert [v.id for v in plan.manifest.vehicles] == ["0759", "3040"]
    assert plan.skipped == ["damaged.obs: not read (header has no END OF HEADER line)"]
    with pytest.raises(RecordingError, match=r"damaged\.obs: header has no END OF HEADER"):
        plan_recording(rec, vehicles={"d": Path("damaged.obs")})
    r = runner.invoke(app, ["recording", "init", str(rec), "--vehicle", "0759"])
    assert r.exit_code == 2 and "expected ID=VALUE" in r.output


def test_positions_and_ids(real_data: Path) -> None:
    assert parse_position("header") == "header"
    assert parse_position("-3978241.958, 3382840.234, 3649900.853") == (
        -3978241.958,
        3382840.234,
        3649900.853,
    )
    lat_lon = parse_position("35.134707705,136.977577939,104.853")
    assert lat_lon != "header" and np.allclose(
        lat_lon, (-3817681.1213, 3562839.4311, 3650159.1593), atol=1e-3
    )
    for bad in ("1,2", "a,b,c", "1000,2000,3000", "nan,0,0"):
        with pytest.raises(ConfigError, match="--base-position"):
            parse_position(bad)
    nagoya = real_data / "matrtklib_nagoya_static_20240624"
    base, rover = summarise_obs(nagoya / "base.obs"), summarise_obs(nagoya / "rover.obs")
    assert base.header.marker_name == rover.header.marker_name == "SEPT"  # a receiver's default
    assert vehicle_ids([base, rover]) == ["base", "rover"]  # so the file names, for every vehicle
    assert vehicle_ids([rover], others=[base]) == ["rover"]  # the base shares it too
    geonet = summarise_obs(real_data / GEONET / "07590920.05o")
    assert vehicle_ids([geonet]) == ["0759"] and geonet.interval_s == 30.0 and geonet.doppler_share == 0.0


def test_show_and_the_wrong_days_ephemerides(real_data: Path, tmp_path: Path) -> None:
    """`coplane recording show` on the bundled recording and the KLT drive; GEONET's 2005
    observations with KLT's 2021 navigation file: init says nothing can be positioned, and why."""
    r = runner.invoke(app, ["recording", "show", str(DEFAULT_RECORDING_DIR)])
    assert r.exit_code == 0, r.output
    assert "u1: antenna 1.674 m above the road; truth 600 rows, 100 % of its epochs" in r.output
    assert "ranges: 3244 between 6 pair(s)" in r.output and "0 input problem(s)" in r.output
    r = runner.invoke(app, ["recording", "show", str(real_data / "hk_klt_20210610_f9p_rover_hksc_base")])
    assert r.exit_code == 0 and "klt1: antenna 1.8 m above the road; truth none" in r.output, r.output
    assert "base: hksc1610.obs at 22.3" in r.output
    assert "klt1: 4.2 km from the base at its first SPP fix" in r.output  # DGNSS over 4 km
    # the ephemerides' days: the file's one GPS record of 2020 is named as such
    assert "64 ephemerides from 2021-06-10 (48), 2021-06-09 (15), 2020-11-10 (1)" in " ".join(
        r.output.split()
    )
    mixed = tmp_path / "mixed"
    mixed.mkdir()
    shutil.copy(real_data / GEONET / "07590920.05o", mixed)
    shutil.copy(real_data / "hk_klt_20210610_f9p_rover_hksc_base" / "hksc1610.nav", mixed)
    r = runner.invoke(app, ["recording", "init", str(mixed)])
    assert r.exit_code == 0, r.output
    out = " ".join(r.output.split())  # rich wraps the note
    assert "nothing can be positioned" in out and "hksc1610.nav" in out
    # the days the ephemerides are from, most first: the file's one stray GPS record (2020) is
    # named, not taken for a span from 2020 to 2021, which would seem to cover any observation
    assert "are from 2021-06-10 (134), 2021-06-09 (25), 2020-11-10 (1)" in out, out
    assert (
        "the nearest 5701.8 days from the observations, which are from 2005-04-02 00:00:00 .. 00:59:30" in out
    )


@pytest.mark.parametrize("fmt", ["ubx", "rtcm3"])
def test_receiver_logs_as_coplane_convert_writes_them(tmp_path: Path, fmt: str) -> None:
    """A folder of .ubx / .rtcm3 logs: the vehicles' logs, the navigation-only log (not a vehicle),
    truth/<id>.csv and uwb.csv where the format puts them: the same vehicles, files and interval
    as convert's own manifest; the recording opens and positions its vehicles."""
    out = tmp_path / fmt
    source = simulate("urban-loop", tmp_path / "sim", vehicles=2, duration_s=30, seed=12)
    convert_recording(source, fmt, out)  # type: ignore[arg-type]  # the parametrised Format
    ref = load_manifest(out)
    (out / "fleet.toml").unlink()
    plan = plan_recording(
        out,
        base=ref.base.obs if ref.base else None,
        base_position=ref.base.position_ecef_m if ref.base else None,
    )
    m = plan.manifest
    assert [(v.id, v.obs, v.truth) for v in m.vehicles] == [(v.id, v.obs, v.truth) for v in ref.vehicles]
    # every log with ephemerides is merged (a receiver's own may miss satellites another has)
    assert set(ref.nav_files) <= set(m.nav_files) and m.interval_s == ref.interval_s
    assert all(p.suffix in (".ubx", ".rtcm3", ".rnx") for p in m.nav_files)
    assert m.uwb is not None and ref.uwb is not None and m.uwb.file == ref.uwb.file
    assert {plan.roles[p] for p in plan.summaries} == {"base", "u1", "u2"}
    path = write_plan(plan)
    rec = open_recording(path)
    assert rec.nav.ephemerides and len(rec.vehicle_epochs("u1")) == 30


def test_a_reference_of_another_day_is_noted(real_data: Path, tmp_path: Path) -> None:
    """UrbanNav's ground truth (2021-05-17) given for the KLT drive (2021-06-10): init converts it
    and says that it covers none of the vehicle's epochs, with both spans, instead of a recording
    whose errors would then be computed on nothing without a word."""
    klt = real_data / "hk_klt_20210610_f9p_rover_hksc_base"
    rec = tmp_path / "klt"
    rec.mkdir()
    for name in ("20210610.klt1.ublox.f9p.obs", "hksc1610.nav"):
        shutil.copy(klt / name, rec)
    truth = real_data / "urbannav_hk_medium_urban1_20210517_kinematic_NONAV" / "UrbanNav_TST_GT_raw.txt"
    plan = plan_recording(rec, vehicles={"klt1": Path("20210610.klt1.ublox.f9p.obs")}, truth={"klt1": truth})
    assert (
        "klt1: its truth covers 0 of its 205 epochs: the trajectory is from 2021-05-17 02:33:13 .. "
        "02:46:19, the observations from 2021-06-10 03:35:54 .. 03:39:18 (GPS time)"
    ) in plan.notes, plan.notes
    # a reference over the drive's own epochs (an RTKLIB .pos, week and seconds, ECEF): no such note
    times = summarise_obs(rec / "20210610.klt1.ublox.f9p.obs").times
    pos = tmp_path / "klt1.pos"
    rows = "".join(f"{t.week} {t.tow:.3f} -2417841.641 5384776.618 2408312.560 1 11\n" for t in times)
    pos.write_text("%  GPST  x-ecef(m)  y-ecef(m)  z-ecef(m)  Q  ns\n" + rows)
    own = plan_recording(rec, vehicles={"klt1": Path("20210610.klt1.ublox.f9p.obs")}, truth={"klt1": pos})
    assert [n for n in own.notes if "klt1: truth/klt1.csv converted" in n] and not [
        n for n in own.notes if "covers" in n
    ], own.notes
