"""Reference trajectories from other tools (`recording.trajectories`, `recording init --truth ID=FILE`):
UrbanNav's real Inertial Explorer ground truth, every RTKLIB .pos layout, bad rows, refusals."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from coplane.errors import ConfigError
from coplane.geo import ecef_to_geodetic, enu_rotation, geodetic_to_ecef
from coplane.gtime import GpsTime
from coplane.recording.discover import summarise_obs
from coplane.recording.plan import plan_recording, write_plan
from coplane.recording.problems import Problems, RecordingError
from coplane.recording.reader import open_recording
from coplane.recording.trajectories import read_pos, read_trajectory, sniff

URBANNAV = "urbannav_hk_medium_urban1_20210517_kinematic_NONAV"
NAGOYA = "matrtklib_nagoya_static_20240624"
LLH_HEADER = (
    "%  {system}                  latitude(deg) longitude(deg)  height(m)   Q  ns   sdn(m)   sde(m)   sdu(m)"
    "  sdne(m)  sdeu(m)  sdun(m) age(s)  ratio"
)
XYZ_HEADER = (
    "%  GPST                  x-ecef(m)      y-ecef(m)      z-ecef(m)   Q  ns   sdx(m)   sdy(m)   sdz(m)"
    "  sdxy(m)  sdyz(m)  sdzx(m) age(s)  ratio"
)
DMS_HEADER = (
    "%  GPST                  latitude(d'\")   longitude(d'\")  height(m)   Q  ns   sdn(m)   sde(m)   sdu(m)"
    "  sdne(m)  sdeu(m)  sdun(m) age(s)  ratio"
)
SD = "0.0040 0.0030 0.0090 0.0010 -0.0010 0.0020 1.00 999.9"


def _dms(value: float) -> str:
    """Degrees as RTKLIB and Inertial Explorer print them: "-D MM SS.SSSSS"."""
    a = abs(value)
    d = int(a)
    m = int((a - d) * 60.0)
    s = ((a - d) * 60.0 - m) * 60.0
    return f"{'-' if value < 0 else ''}{d} {m:02d} {s:08.5f}"


def _calendar(t: GpsTime) -> str:
    y, mo, d, hh, mi, s = t.to_calendar()
    return f"{y:04d}/{mo:02d}/{d:02d} {hh:02d}:{mi:02d}:{s:06.3f}"


def _points(n: int = 5) -> list[tuple[GpsTime, float, float, float]]:
    """A short drive south-west of Greenwich: negative latitude minutes test the signs."""
    t0 = GpsTime(2320, 116400.0)
    return [(t0 + k, -33.8688 - 1e-5 * k, 151.2093 + 2e-5 * k, 40.0 + 0.01 * k) for k in range(n)]


def _ecef(lat: float, lon: float, h: float) -> np.ndarray:
    return geodetic_to_ecef(math.radians(lat), math.radians(lon), h)


def _write(path: Path, lines: list[str]) -> Path:
    path.write_text("\n".join(lines) + "\n")
    return path


def _layouts(tmp_path: Path) -> dict[str, Path]:
    """The same points in the layouts RTKLIB writes (outsolheads/outsols)."""
    pts = _points()
    out = {
        "llh, calendar GPST": _write(
            tmp_path / "llh.pos",
            ["% (lat/lon/height=WGS84/ellipsoidal,Q=1:fix,...)", LLH_HEADER.format(system="GPST")]
            + [f"{_calendar(t)} {la:14.9f} {lo:14.9f} {h:10.4f} 1 20 {SD}" for t, la, lo, h in pts],
        ),
        "xyz, week and seconds": _write(
            tmp_path / "xyz.pos",
            [XYZ_HEADER]
            + [
                f"{t.week} {t.tow:.3f} " + " ".join(f"{c:.4f}" for c in _ecef(la, lo, h)) + f" 1 20 {SD}"
                for t, la, lo, h in pts
            ],
        ),
        "dms": _write(
            tmp_path / "dms.pos",
            [DMS_HEADER]
            + [f"{_calendar(t)} {_dms(la)} {_dms(lo)} {h:10.4f} 1 20 {SD}" for t, la, lo, h in pts],
        ),
        "llh, UTC": _write(
            tmp_path / "utc.pos",
            [LLH_HEADER.format(system="UTC")]
            + [f"{_calendar(t + -18.0)} {la:.9f} {lo:.9f} {h:.4f} 1 20 {SD}" for t, la, lo, h in pts],
        ),
        "llh, JST": _write(
            tmp_path / "jst.pos",
            [LLH_HEADER.format(system="JST")]
            + [
                f"{_calendar(t + (9 * 3600 - 18.0))} {la:.9f} {lo:.9f} {h:.4f} 1 20 {SD}"
                for t, la, lo, h in pts
            ],
        ),
        "llh, comma separated": _write(
            tmp_path / "comma.pos",
            [LLH_HEADER.format(system="GPST")]
            + [
                f"{_calendar(t)},{la:.9f},{lo:.9f},{h:.4f},1,20," + SD.replace(" ", ",")
                for t, la, lo, h in pts
            ],
        ),
        "xyz, no header": _write(
            tmp_path / "bare.pos",
            [
                f"{t.week} {t.tow:.3f} " + " ".join(f"{c:.4f}" for c in _ecef(la, lo, h)) + f" 5 20 {SD}"
                for t, la, lo, h in pts
            ],
        ),
    }
    return out


def test_every_rtklib_layout_gives_the_same_trajectory(tmp_path: Path) -> None:
    want = [(t, _ecef(la, lo, h)) for t, la, lo, h in _points()]
    for layout, path in _layouts(tmp_path).items():
        problems = Problems()
        assert sniff(path) == "pos", layout
        got = read_trajectory(path, problems)
        assert not problems, layout
        assert [p.time for p in got.points] == [t for t, _ in want], layout
        for p, (_, xyz) in zip(got.points, want, strict=True):
            # 1e-9 degrees is 0.1 mm; the d m s layout prints 1e-5 seconds, 0.3 mm
            assert np.linalg.norm(np.asarray(p.ecef_m) - xyz) < 1e-3, layout


def test_rtklib_standard_deviations_become_the_ecef_covariance(tmp_path: Path) -> None:
    """Signed square roots (RTKLIB's sdne etc.), north-east-up rotated to ECEF; ECEF as written."""
    layouts = _layouts(tmp_path)
    llh = read_pos(layouts["llh, calendar GPST"], Problems())[0]
    sn, se, su, sne, seu, sun = 0.004, 0.003, 0.009, 0.001, -0.001, 0.002
    enu = np.array(
        [[se**2, sne**2, -(seu**2)], [sne**2, sn**2, sun**2], [-(seu**2), sun**2, su**2]]
    )  # east, north, up
    lat, lon, _ = ecef_to_geodetic(llh.ecef)
    rot = enu_rotation(lat, lon)
    np.testing.assert_allclose(rot @ llh.covariance @ rot.T, enu, atol=1e-12)
    xyz = read_pos(layouts["xyz, no header"], Problems())[0]
    assert xyz.quality == 5 and xyz.n_sats == 20
    np.testing.assert_allclose(
        xyz.covariance, [[sn**2, sne**2, sun**2], [sne**2, se**2, -(seu**2)], [sun**2, -(seu**2), su**2]]
    )


def test_an_rtk_reference_keeps_its_fixed_rows_only(tmp_path: Path) -> None:
    pts = _points(10)
    path = _write(
        tmp_path / "rtk.pos",
        [LLH_HEADER.format(system="GPST")]
        + [
            f"{_calendar(t)} {la:.9f} {lo:.9f} {h:.4f} {2 if k % 3 == 0 else 1} 20 {SD}"
            for k, (t, la, lo, h) in enumerate(pts)
        ],
    )
    traj = read_trajectory(path, Problems())
    assert [p.time for p in traj.points] == [t for k, (t, *_) in enumerate(pts) if k % 3]
    assert traj.left_out == 4 and traj.qualities == {1: 6, 2: 4}
    assert (
        "fix 6, float 4" in traj.describe() and "4 rows without a fixed ambiguity left out" in traj.describe()
    )
    code_only = read_trajectory(_layouts(tmp_path)["xyz, no header"], Problems())
    assert len(code_only.points) == 5 and "no row has a fixed ambiguity" in code_only.describe()


def test_bad_rows_are_counted_with_their_line_and_the_rest_kept(tmp_path: Path) -> None:
    pts = _points(4)
    rows = [f"{_calendar(t)} {la:.9f} {lo:.9f} {h:.4f} 1 20 {SD}" for t, la, lo, h in pts]
    path = _write(
        tmp_path / "bad.pos",
        [
            LLH_HEADER.format(system="GPST"),
            rows[0],
            "2024/06/24 08:20:01.000 garbage",
            rows[1],
            f"{_calendar(pts[2][0])} nan 151.2 40.0 1 20 {SD}",
            f"{_calendar(pts[2][0])} 95.0 151.2 40.0 1 20 {SD}",
            rows[2],
            rows[1],  # a second solution at one time
            rows[3],
        ],
    )
    problems = Problems()
    traj = read_trajectory(path, problems)
    assert [p.time for p in traj.points] == [p[0] for p in pts]
    assert problems.total == 4
    assert [p.line for p in problems.items[:3]] == [3, 5, 6]
    assert problems.counts["duplicate-row"] == 1
    assert "latitude 95.0" in problems.items[2].reason


def test_what_cannot_be_a_reference_is_refused_by_name(tmp_path: Path) -> None:
    geoid = _write(
        tmp_path / "msl.pos", ["% (lat/lon/height=WGS84/geodetic,Q=1:fix)", LLH_HEADER.format(system="GPST")]
    )
    with pytest.raises(RecordingError, match=r"geoid.*out-height=ellipsoidal"):
        read_pos(geoid, Problems())
    baseline = _write(
        tmp_path / "enu.pos",
        [
            "%  GPST   e-baseline(m)  n-baseline(m)  u-baseline(m)   Q  ns",
            "2024/06/24 08:20:00.000 1.0 2.0 3.0 1 20",
        ],
    )
    with pytest.raises(RecordingError, match="baseline"):
        read_pos(baseline, Problems())
    with pytest.raises(RecordingError, match=r"RTKLIB solution file.*Inertial Explorer"):
        sniff(_write(tmp_path / "x.txt", ["time;lat;lon", "1;2;3"]))


def test_urbannav_ground_truth_is_the_m8t_drive(real_data: Path) -> None:
    """UrbanNav's published truth (Inertial Explorer, lat/lon in d m s) covers the M8T's epochs."""
    folder = real_data / URBANNAV
    problems = Problems()
    traj = read_trajectory(folder / "UrbanNav_TST_GT_raw.txt", problems)
    assert not problems and traj.kind == "Inertial Explorer text"
    assert len(traj.points) == 787 and sum(traj.qualities.values()) == 787
    assert traj.points[0].time == GpsTime(2158, 95593.0) and traj.points[-1].time == GpsTime(2158, 96379.0)
    # the first row: 22 18 04.31949, 114 10 44.60559, 3.472 m
    first = _ecef(22 + 18 / 60 + 4.31949 / 3600, 114 + 10 / 60 + 44.60559 / 3600, 3.472)
    assert np.linalg.norm(np.asarray(traj.points[0].ecef_m) - first) < 1e-6
    m8t = summarise_obs(folder / "UrbanNav-HK-Medium-Urban-1.ublox.m8t.GC.obs")
    epochs = {t.round_to(1.0) for t in m8t.times}
    covered = epochs & {p.time for p in traj.points}
    assert len(covered) >= 0.99 * len(epochs)


@pytest.mark.parametrize("kind", ["pos", "ie"])
def test_init_converts_another_tools_trajectory_into_truth(
    real_data: Path, tmp_path: Path, kind: str
) -> None:
    """`recording init --truth ID=FILE` with the Nagoya rover's surveyed point as a trajectory file
    kept outside the recording: truth/ID.csv is written and every epoch is scored against it."""
    root = tmp_path / "rec"
    root.mkdir()
    for name in ("rover.obs", "base.nav"):
        shutil.copy(real_data / NAGOYA / name, root / name)
    lat, lon, h = (float(v) for v in (real_data / NAGOYA / "rover_position.txt").read_text().split())
    t0 = GpsTime.from_calendar(2024, 6, 24, 8, 20, 0.0)
    times = [t0 + k for k in range(301)]
    if kind == "pos":
        lines = [LLH_HEADER.format(system="GPST")]
        lines += [
            f"{_calendar(t)} {lat:.9f} {lon:.9f} {h:.4f} {2 if k == 7 else 1} 25 {SD}"
            for k, t in enumerate(times)
        ]
    else:
        lines = [
            "      UTCTime       Week   GPSTime         Latitude        Longitude        H-Ell  Q",
            "        (sec)    (weeks)     (sec)       (+/-D M S)       (+/-D M S)          (m)   ",
        ]
        lines += [f"0.00 {t.week}.00000 {t.tow:9.2f}   {_dms(lat)}  {_dms(lon)}  {h:11.4f} 1" for t in times]
    given = _write(tmp_path / f"reference.{kind}", lines)
    plan = plan_recording(root, vehicles={"u1": root / "rover.obs"}, truth={"u1": given})
    note = next(n for n in plan.notes if n.startswith("u1: truth/u1.csv converted from"))
    assert ("300 points" if kind == "pos" else "301 points") in note
    write_plan(plan)
    rec = open_recording(root)
    truth = rec.truth_at("u1")
    assert len(truth) == (300 if kind == "pos" else 301) and not rec.problems
    surveyed = _ecef(lat, lon, h)
    assert max(np.linalg.norm(np.asarray(p) - surveyed) for p in truth.values()) < 1e-3


def test_init_refuses_a_trajectory_without_one_usable_point(real_data: Path, tmp_path: Path) -> None:
    root = tmp_path / "rec"
    root.mkdir()
    shutil.copy(real_data / NAGOYA / "rover.obs", root / "rover.obs")
    shutil.copy(real_data / NAGOYA / "base.nav", root / "base.nav")
    given = _write(
        tmp_path / "broken.pos", [LLH_HEADER.format(system="GPST"), "2024/06/24 08:20:00.000 x y z 1 2"]
    )
    with pytest.raises(
        ConfigError,
        match=r"--truth u1 .*broken.pos: no usable point \(1 bad rows, the first: .*broken.pos:2: ",
    ):
        plan_recording(root, vehicles={"u1": root / "rover.obs"}, truth={"u1": given})


def test_rtklibs_own_files_read_alike_in_every_layout(real_data: Path, tmp_path: Path) -> None:
    """RTKLIB itself (pyrtklib's postpos, DGPS of the Nagoya rover) writing ECEF with UTC times,
    latitude / longitude with GPST calendar or week-and-seconds times, and d m s with JST times:
    every file reads without a problem, to the same times, the same positions within what it
    prints (0.1 mm in ECEF, 1e-9 degrees, 1e-5 arc seconds) and the same covariance within the
    rounding of its standard deviations."""
    import pyrtklib as rtk

    from coplane.evaluate.rtklib_row import postpos_files, rtklib_options, run_postpos

    rec = open_recording(real_data / NAGOYA)
    vid = rec.manifest.vehicles[0].id
    assert rec.manifest.base is not None
    files = postpos_files(
        [rec.manifest.vehicle(vid).obs, rec.manifest.base.obs, *rec.manifest.nav_files], tmp_path
    )
    layouts = {
        "xyz, UTC": (rtk.SOLF_XYZ, 1, rtk.TIMES_UTC, 0),
        "llh, GPST": (rtk.SOLF_LLH, 1, rtk.TIMES_GPST, 0),
        "llh, week and seconds": (rtk.SOLF_LLH, 0, rtk.TIMES_GPST, 0),
        "dms, JST": (rtk.SOLF_LLH, 1, rtk.TIMES_JST, 1),
    }
    read = {}
    for name, (posf, timef, times, degf) in layouts.items():
        opt, sopt = rtklib_options(rec, True, 10.0)
        sopt.posf, sopt.timef, sopt.times, sopt.degf = posf, timef, times, degf
        ret, _ = run_postpos(opt, sopt, files, tmp_path / f"{len(read)}.pos")
        problems = Problems()
        read[name] = {r.time: r for r in read_pos(tmp_path / f"{len(read)}.pos", problems)}
        assert ret == 0 and not problems and len(read[name]) == 301, name
    ref = read["xyz, UTC"]
    for name, rows in read.items():
        assert rows.keys() == ref.keys(), name
        for t, r in rows.items():
            assert np.linalg.norm(r.ecef - ref[t].ecef) < 1e-3, name
            np.testing.assert_allclose(
                r.covariance, ref[t].covariance, rtol=0, atol=2e-3 * np.abs(ref[t].covariance).max()
            )
