"""`coplane recording init` joins one receiver's consecutive files (a CORS's hourly RINEX, a logger's
rotated UBX or RTCM 3 logs).

The real files are cut in two at an epoch, as a network's hourly files are, each half with the
whole header: init must join them back into one file that reads as the uncut one, and must never
join receivers that logged at the same time.
"""

from __future__ import annotations

import gzip
import re
import shutil
from pathlib import Path

import hatanaka
import pytest

from coplane.recording.discover import receiver_files
from coplane.recording.plan import plan_recording, write_plan
from coplane.recording.problems import Problems
from coplane.recording.reader import open_recording
from coplane.recording.rinex_nav import read_nav
from coplane.recording.rinex_obs import read_obs
from coplane.recording.rtcm3 import write_rtcm3
from coplane.recording.ubx import write_ubx

GEONET = "rtklib_geonet_0759_3040_20050402"
NAGOYA = "matrtklib_nagoya_static_20240624"
BASE_3040 = (-3978241.958, 3382840.234, 3649900.853)
_EPOCH2 = re.compile(r"^ \d\d [ \d]\d [ \d]\d [ \d]\d (?P<minute>[ \d]\d) [ \d]\d\.\d{7}  0")


def _cut(src: Path, first: Path, second: Path, at: int) -> None:
    """`src` as two files, each with its header: the records before body line `at`, and the rest."""
    lines = src.read_text(encoding="latin-1").splitlines(keepends=True)
    end = next(i for i, x in enumerate(lines) if "END OF HEADER" in x) + 1
    first.write_text("".join(lines[: end + at]), encoding="latin-1")
    second.write_text("".join(lines[:end] + lines[end + at :]), encoding="latin-1")
    src.unlink()


def _body_index(path: Path, pattern: re.Pattern[str], pick: int) -> int:
    lines = path.read_text(encoding="latin-1").splitlines()
    end = next(i for i, x in enumerate(lines) if "END OF HEADER" in x) + 1
    return [i - end for i in range(end, len(lines)) if pattern.match(lines[i])][pick]


def test_a_reference_stations_hourly_files_become_one(real_data: Path, tmp_path: Path) -> None:
    """GEONET's base (RINEX 2.10, with splice event records) cut at 00:30, the second half compressed;
    the base is named by its first half."""
    root = tmp_path / "geonet"
    shutil.copytree(real_data / GEONET, root, ignore=shutil.ignore_patterns("fleet.toml", "truth"))
    src = root / "30400920.05o"
    want_header, want = read_obs(src, Problems())
    at = _body_index(src, _EPOCH2, 60)  # the 61st epoch: 00:30:00
    _cut(src, root / "3040092a.05o", root / "3040092b.05o", at)
    second = root / "3040092b.05d.Z"  # as networks publish it: Compact RINEX, Unix-compressed
    second.write_bytes(hatanaka.compress((root / "3040092b.05o").read_bytes(), compression="Z"))
    (root / "3040092b.05o").unlink()
    plan = plan_recording(root, base=Path("3040092a.05o"), base_position=BASE_3040)
    joined = root / "spliced" / "3040092a-spliced.05o"
    assert plan.splices == {joined: (root / "3040092a.05o", second)}
    assert plan.manifest.base is not None and plan.manifest.base.obs == joined
    assert [v.id for v in plan.manifest.vehicles] == ["0759"]
    assert any("joined as spliced/3040092a-spliced.05o" in n for n in plan.notes)
    assert plan.summaries[joined].epochs == len([e for e in want if e.flag <= 1]) == 120
    assert not joined.exists()  # a plan writes nothing
    write_plan(plan)
    got_header, got = read_obs(joined, Problems())
    assert got == want and got_header.obs_types == want_header.obs_types
    assert open_recording(root).base_epochs()  # the recording opens on the joined file
    # init again: the joined file is not found as a receiver of its own
    assert all("spliced" not in r.path.parts for r in receiver_files(root))
    assert plan_recording(root, base=Path("3040092a.05o"), base_position=BASE_3040).splices == plan.splices


def test_receivers_logging_together_are_never_joined(real_data: Path, tmp_path: Path) -> None:
    """Nagoya's rover and base share marker and receiver (SEPT, mosaic-X5) but log at the same time;
    the rover's own two halves are joined, and only them."""
    root = tmp_path / "nagoya"
    shutil.copytree(real_data / NAGOYA, root, ignore=shutil.ignore_patterns("fleet.toml", "truth"))
    at = _body_index(root / "rover.obs", re.compile(r"^> "), 150)
    _cut(root / "rover.obs", root / "rover_a.obs", root / "rover_b.obs", at)
    plan = plan_recording(root)
    assert list(plan.splices.values()) == [(root / "rover_a.obs", root / "rover_b.obs")]
    assert sorted(p.name for p in plan.summaries) == ["base.obs", "rover_a-spliced.obs"]
    # named as two receivers by the user: left apart, and said so
    plan = plan_recording(root, vehicles={"a": Path("rover_a.obs"), "b": Path("rover_b.obs")})
    assert not plan.splices and any("named as a and b: not joined" in n for n in plan.notes)


def test_a_named_receivers_continuation_is_found_and_joined(real_data: Path, tmp_path: Path) -> None:
    """`--vehicle` and `--base` name the first hour's files: the next hour's are still read, only to
    join them to the named ones; files named by nobody stay out of the recording, and say so."""
    root = tmp_path / "geonet"
    shutil.copytree(real_data / GEONET, root, ignore=shutil.ignore_patterns("fleet.toml", "truth"))
    for name, n_epochs in (("30400920.05o", 60), ("07590920.05o", 60)):
        src = root / name
        _cut(src, root / f"{name[:7]}a.05o", root / f"{name[:7]}b.05o", _body_index(src, _EPOCH2, n_epochs))
    shutil.copy(real_data / NAGOYA / "rover.obs", root / "spare.obs")  # a receiver named by nobody
    plan = plan_recording(
        root, vehicles={"rover": Path("0759092a.05o")}, base=Path("3040092a.05o"), base_position=BASE_3040
    )
    joined_rover = root / "spliced" / "0759092a-spliced.05o"
    joined_base = root / "spliced" / "3040092a-spliced.05o"
    assert plan.splices == {
        joined_rover: (root / "0759092a.05o", root / "0759092b.05o"),
        joined_base: (root / "3040092a.05o", root / "3040092b.05o"),
    }
    assert [(v.id, v.obs) for v in plan.manifest.vehicles] == [("rover", joined_rover)]
    assert plan.manifest.base is not None and plan.manifest.base.obs == joined_base
    assert sorted(plan.summaries) == sorted([joined_rover, joined_base])
    assert plan.summaries[joined_rover].epochs == plan.summaries[joined_base].epochs == 120
    assert "spare.obs: not named with --vehicle" in plan.skipped


@pytest.mark.parametrize("gap_s", [0.0, 120.0])
def test_overlapping_or_distant_files_are_not_joined(real_data: Path, tmp_path: Path, gap_s: float) -> None:
    """The second half starting where the first ended (an overlap) or two minutes after: apart."""
    root = tmp_path / "nagoya"
    shutil.copytree(
        real_data / NAGOYA, root, ignore=shutil.ignore_patterns("fleet.toml", "truth", "base.obs")
    )
    rover = root / "rover.obs"
    _cut(rover, root / "rover_a.obs", root / "rover_b.obs", _body_index(rover, re.compile(r"^> "), 150))
    if gap_s == 0.0:  # the first half's last epoch again at the start of the second
        a = (root / "rover_a.obs").read_text(encoding="latin-1").splitlines(keepends=True)
        last = max(i for i, x in enumerate(a) if x.startswith("> "))
        b = (root / "rover_b.obs").read_text(encoding="latin-1").splitlines(keepends=True)
        end = next(i for i, x in enumerate(b) if "END OF HEADER" in x) + 1
        (root / "rover_b.obs").write_text("".join(b[:end] + a[last:] + b[end:]), encoding="latin-1")
    else:  # drop the second half's first two minutes
        b = (root / "rover_b.obs").read_text(encoding="latin-1").splitlines(keepends=True)
        end = next(i for i, x in enumerate(b) if "END OF HEADER" in x) + 1
        starts = [i for i in range(end, len(b)) if b[i].startswith("> ")]
        (root / "rover_b.obs").write_text("".join(b[:end] + b[starts[121] :]), encoding="latin-1")
    plan = plan_recording(root)
    assert not plan.splices
    assert any("122 s apart (more than 60): not joined" in n for n in plan.notes) == (gap_s > 0)


@pytest.mark.parametrize(("fmt", "cut"), [("ubx", "epoch"), ("rtcm3", "epoch"), ("ubx", "byte")])
def test_a_loggers_rotated_logs_become_one(real_data: Path, tmp_path: Path, fmt: str, cut: str) -> None:
    """Nagoya's rover written as a receiver log cut in two, at its 150th epoch (each half with the
    ephemerides) or in the middle of a message as a logger's rotation by size cuts it, the second
    half gzipped; the base logged beside it over the same minutes. The rover's halves are joined
    (the joined log also gives the ephemerides), the base is not joined to either."""
    root = tmp_path / "nagoya"
    root.mkdir()
    _, rover = read_obs(real_data / NAGOYA / "rover.obs", Problems())
    _, base = read_obs(real_data / NAGOYA / "base.obs", Problems())
    nav = read_nav(real_data / NAGOYA / "base.nav", Problems())
    write = write_ubx if fmt == "ubx" else (lambda p, e, nav=None: write_rtcm3(p, e, nav))
    if cut == "epoch":
        write(root / f"rover_a.{fmt}", rover[:150], nav=nav)
        write(root / f"rover_b.{fmt}", rover[150:], nav=nav)
    else:
        data = write(tmp_path / f"rover.{fmt}", rover, nav=nav).read_bytes()
        (root / f"rover_a.{fmt}").write_bytes(data[: len(data) // 2])
        (root / f"rover_b.{fmt}").write_bytes(data[len(data) // 2 :])
    second = root / f"rover_b.{fmt}.gz"
    second.write_bytes(gzip.compress((root / f"rover_b.{fmt}").read_bytes()))
    (root / f"rover_b.{fmt}").unlink()
    write(root / f"base.{fmt}", base, nav=nav)
    plan = plan_recording(root)
    joined = root / "spliced" / f"rover_a-spliced.{fmt}"
    assert plan.splices == {joined: (root / f"rover_a.{fmt}", second)}
    assert sorted(p.name for p in plan.summaries) == [f"base.{fmt}", joined.name]
    if cut == "epoch":
        assert plan.summaries[joined].epochs == len(rover) == 301
    assert joined in plan.manifest.nav_files and second not in plan.manifest.nav_files
    assert any(f"being {fmt.upper()} logs with the same signals, joined as" in n for n in plan.notes)
    write_plan(plan)
    rec = open_recording(root)
    vid = next(v.id for v in rec.manifest.vehicles if v.obs == joined)
    assert [e.time for e in rec.vehicle_epochs(vid)] == [e.time for e in rover]  # the cut message too
    assert not rec.problems
