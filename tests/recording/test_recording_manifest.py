"""fleet.toml validation on the hand-made variants in tests/data/broken/fleet, and write -> load."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from coplane.recording.manifest import load_manifest, write_manifest
from coplane.recording.model import BaseSpec, Manifest, UwbSpec, VehicleSpec
from coplane.recording.problems import RecordingError

FLEET = Path(__file__).resolve().parents[1] / "data" / "broken" / "fleet"


def test_valid_manifest_resolves_paths_and_ignores_unknown_keys() -> None:
    m = load_manifest(FLEET)
    root = FLEET.resolve()
    assert m.root == root
    assert m.name == "hand-made broken fleet"
    assert m.interval_s == 1.0
    assert m.nav_files == (root / "nav" / "brdc.rnx",)
    assert m.base == BaseSpec(root / "base" / "ref.obs", (-3817681.1213, 3562839.4311, 3650159.1593))
    assert m.vehicles == (
        VehicleSpec("u1", root / "vehicles" / "u1.obs", 1.85, root / "truth" / "u1.csv"),
        VehicleSpec("u2", root / "vehicles" / "u2.obs", 1.62, None),
    )
    assert m.uwb == UwbSpec(root / "uwb.csv", 0.3, 500.0)
    assert load_manifest(FLEET / "fleet.toml") == m  # the file itself may be given


# (file, text the error must contain: the key or the path)
BAD = [
    ("bad_missing_format.toml", "format: required key is missing"),
    ("bad_format.toml", "fleet-recording/2"),
    ("bad_duplicate_id.toml", "vehicles[1].id: duplicate vehicle id 'u1'"),
    ("bad_id.toml", "vehicles[1].id: invalid vehicle id"),
    ("bad_traversal.toml", "vehicles[1].obs: path '../x.obs' leaves the recording directory"),
    ("bad_traversal_existing.toml", "vehicles[1].obs: path '../clean_v3.obs' leaves the recording directory"),
    ("bad_absolute.toml", "nav.files[0]: path '/etc/hostname' leaves the recording directory"),
    ("bad_missing_file.toml", "vehicles[0].truth: file 'truth/u9.csv' does not exist"),
    ("bad_missing_interval.toml", "time.interval_s: required key is missing"),
    ("bad_missing_vehicle_obs.toml", "vehicles[1].obs: required key is missing"),
    ("bad_position.toml", "base.position_ecef_m: must be a list of 3 numbers"),
    ("bad_syntax.toml", "not valid TOML"),
    ("bad_interval.toml", "time.interval_s: must be positive"),
]


@pytest.mark.parametrize(("name", "message"), BAD, ids=[b[0] for b in BAD])
def test_bad_manifest_names_the_key_or_path(name: str, message: str) -> None:
    with pytest.raises(RecordingError) as exc:
        load_manifest(FLEET / name)
    assert message in str(exc.value)
    assert name in str(exc.value)


def test_not_a_recording(tmp_path: Path) -> None:
    with pytest.raises(RecordingError, match=r"no fleet\.toml .*`coplane recording init"):
        load_manifest(tmp_path)
    # a path that does not exist is a typo, not a folder that needs a manifest
    with pytest.raises(RecordingError, match=r"nope: no such directory$"):
        load_manifest(tmp_path / "nope")


def test_symlink_leaving_the_recording_is_rejected(tmp_path: Path) -> None:
    rec = tmp_path / "rec"
    shutil.copytree(FLEET, rec)
    (tmp_path / "outside.obs").write_text("x")
    (rec / "vehicles" / "u2.obs").unlink()
    (rec / "vehicles" / "u2.obs").symlink_to(tmp_path / "outside.obs")
    with pytest.raises(RecordingError, match=r"vehicles\[1\]\.obs: path 'vehicles/u2.obs' leaves"):
        load_manifest(rec)


def test_write_then_load_round_trip(tmp_path: Path) -> None:
    rec = tmp_path / "rec"
    shutil.copytree(FLEET, rec)
    (rec / "fleet.toml").unlink()
    m = Manifest(
        root=rec,
        name="round trip",
        interval_s=0.5,
        nav_files=(rec / "nav" / "brdc.rnx",),
        vehicles=(
            VehicleSpec("u1", Path("vehicles/u1.obs"), 1.5, rec / "truth" / "u1.csv"),
            VehicleSpec("u_2-x", rec / "vehicles" / "u2.obs", 1.25),
        ),
        base=BaseSpec(rec / "base" / "ref.obs", (1.0, 2.0, 6.4e6)),
        uwb=UwbSpec(rec / "uwb.csv", 0.25, 300.0),
    )
    path = write_manifest(m)
    text = path.read_text()
    assert 'format = "fleet-recording/1"' in text and str(tmp_path) not in text  # relative paths only
    back = load_manifest(rec)
    assert back.vehicles[0].obs == (rec / "vehicles" / "u1.obs").resolve()
    assert back.interval_s == 0.5 and back.uwb == UwbSpec((rec / "uwb.csv").resolve(), 0.25, 300.0)
    assert [v.id for v in back.vehicles] == ["u1", "u_2-x"]
    assert write_manifest(back).read_text() == text  # deterministic
    assert not list(rec.glob(".fleet.toml.*"))  # replaced whole, no temporary left behind


def test_write_manifest_rejects_bad_ids_and_outside_paths(tmp_path: Path) -> None:
    base = Manifest(tmp_path, "x", 1.0, (tmp_path / "n.rnx",), (VehicleSpec("ok", tmp_path / "a.obs", 1.0),))
    with pytest.raises(RecordingError, match="invalid"):
        write_manifest(Manifest(tmp_path, "x", 1.0, (), (VehicleSpec("no way", tmp_path / "a.obs", 1.0),)))
    with pytest.raises(RecordingError, match="not inside"):
        write_manifest(Manifest(tmp_path, "x", 1.0, (Path("/etc/hostname"),), base.vehicles))
