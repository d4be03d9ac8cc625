"""Compressed RINEX (gzip, Unix compress, bzip2, Compact RINEX) read as the plain files are.

The compressed copies are made here from the real sets with the `hatanaka` package (RNXCMP's
rnx2crx and the archive formats), named as reference-station networks name them.
"""

from __future__ import annotations

import bz2
import gzip
import shutil
import zipfile
from pathlib import Path

import hatanaka
import ncompress
import pytest
from typer.testing import CliRunner

from coplane.cli import app
from coplane.evaluate.evaluation import evaluate
from coplane.recording import compressed
from coplane.recording.compressed import file_format, is_compressed, plain_file, plain_name
from coplane.recording.convert import convert_recording
from coplane.recording.discover import sniff
from coplane.recording.plan import plan_recording, write_plan
from coplane.recording.problems import Problems, RecordingError
from coplane.recording.reader import open_recording
from coplane.recording.rinex_nav import read_nav
from coplane.recording.rinex_obs import read_obs
from coplane.sim.generate import simulate

runner = CliRunner()
GEONET = "rtklib_geonet_0759_3040_20050402"


def test_names() -> None:
    assert plain_name("hksc1370.21d.Z") == "hksc1370.21o"
    assert plain_name("HKSC00HKG_R_20211370000_01D_30S_MO.crx.gz") == "HKSC00HKG_R_20211370000_01D_30S_MO.rnx"
    assert plain_name("brdc1370.21n.gz") == "brdc1370.21n"
    assert plain_name("rover.obs.bz2") == "rover.obs"
    assert plain_name("rover.obs") == "rover.obs" and not is_compressed(Path("rover.obs"))
    assert [file_format(Path(n)) for n in ("u1.ubx.gz", "b.RTCM3", "x.21d.Z", "x.obs")] == [
        "ubx",
        "rtcm3",
        "rinex",
        "rinex",
    ]


@pytest.mark.parametrize(
    ("folder", "name"),
    [
        ("urbannav_hk_tst_20200603_static_f9p", "2020_06_03_TST_03.obs"),  # RINEX 3.02, CRLF
        (GEONET, "07590920.05o"),  # RINEX 2.10 with splice event records
    ],
)
@pytest.mark.parametrize("compression", ["gz", "Z", "bz2", "crx"])
def test_observations_read_as_the_plain_file(
    real_data: Path, tmp_path: Path, folder: str, name: str, compression: str
) -> None:
    plain = real_data / folder / name
    if compression == "crx":  # Compact RINEX alone
        packed = hatanaka.rnx2crx(plain.read_bytes())
        target = tmp_path / (name[:-4] + ".crx" if name.endswith(".obs") else name[:-1] + "d")
    else:  # Compact RINEX, then archived: what a CORS publishes
        packed = hatanaka.compress(plain.read_bytes(), compression=compression)
        crx = name[:-4] + ".crx" if name.endswith(".obs") else name[:-1] + "d"
        target = tmp_path / f"{crx}.{compression}"
    target.write_bytes(packed)
    assert is_compressed(target)
    want_header, want = read_obs(plain, Problems())
    got_header, got = read_obs(target, Problems())
    assert got == want and got_header == want_header
    assert sniff(target) is not None and sniff(target).kind == "obs"  # type: ignore[union-attr]


def test_navigation_and_a_broken_archive(real_data: Path, tmp_path: Path) -> None:
    plain = real_data / GEONET / "07590920.05n"
    gz = tmp_path / "07590920.05n.gz"
    gz.write_bytes(hatanaka.compress(plain.read_bytes(), compression="gz"))
    assert read_nav(gz, Problems()) == read_nav(plain, Problems())
    out = tmp_path / "out"
    out.mkdir()
    assert (
        plain_file(gz, out) == out / "07590920.05n"
        and (out / "07590920.05n").read_bytes() == plain.read_bytes()
    )
    assert plain_file(plain, out) == plain  # a plain file is used where it is
    broken = tmp_path / "broken.05o.gz"
    broken.write_bytes(gz.read_bytes()[:200])  # cut short, as an interrupted download leaves it
    with pytest.raises(
        RecordingError, match=r"broken\.05o\.gz: cannot decompress \(the archive is cut short\)"
    ):
        read_obs(broken, Problems())
    fake = tmp_path / "fake.05n.gz"
    fake.write_bytes(b"\x1f\x8b" + bytes(range(256)) * 4)  # gzip's magic, then no gzip
    with pytest.raises(RecordingError, match=r"fake\.05n\.gz: cannot decompress \(error"):
        read_nav(fake, Problems())
    assert sniff(fake) is not None and sniff(fake).kind == "other"  # type: ignore[union-attr]
    # named as compressed but plain: read as it is
    (tmp_path / "plain.05n.gz").write_bytes(plain.read_bytes())
    assert read_nav(tmp_path / "plain.05n.gz", Problems()) == read_nav(plain, Problems())
    # two gzip members end to end (as `cat a.gz b.gz` makes), then padding: one file
    half = len(plain.read_bytes()) // 2
    two = tmp_path / "two.05n.gz"
    two.write_bytes(
        gzip.compress(plain.read_bytes()[:half]) + gzip.compress(plain.read_bytes()[half:]) + b"\0" * 8
    )
    assert read_nav(two, Problems()) == read_nav(plain, Problems())


def test_a_crafted_archive_cannot_exhaust_memory(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A few kB that would decompress to gigabytes: stopped at the bound, with the file named."""
    monkeypatch.setattr(compressed, "MAX_PLAIN_BYTES", 1 << 20)  # 1 MiB here, 2 GiB in use
    for name, packed in (
        ("bomb.obs.gz", gzip.compress(bytes(4 << 20))),
        ("bomb.obs.bz2", bz2.compress(bytes(4 << 20))),
        ("bomb.obs.Z", ncompress.compress(bytes(4 << 20))),
    ):
        (tmp_path / name).write_bytes(packed)
        assert len(packed) < 20_000
        with pytest.raises(RecordingError, match=rf"{name}: more than .* GiB once decompressed"):
            read_obs(tmp_path / name, Problems())
        # telling what a file is decompresses its first kB only: no bound reached, not RINEX
        assert sniff(tmp_path / name) is None
    zipped = tmp_path / "bomb.obs.zip"
    with zipfile.ZipFile(zipped, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("bomb.obs", bytes(4 << 20))
    with pytest.raises(RecordingError, match="once decompressed"):
        read_obs(zipped, Problems())


def test_a_compressed_folder_end_to_end(real_data: Path, tmp_path: Path) -> None:
    """GEONET's four files as a network would serve them (.05d.Z observations, .05n.gz navigation):
    recording init, then non-cp and RTKLIB's row (fed plain copies) as on the plain files."""
    plain_dir, packed_dir = tmp_path / "plain", tmp_path / "packed"
    shutil.copytree(real_data / GEONET, plain_dir)
    packed_dir.mkdir()
    for f in sorted(plain_dir.iterdir()):
        obs = f.name.endswith("o")
        packed = hatanaka.compress(f.read_bytes(), compression="Z" if obs else "gz")
        (packed_dir / (f.name[:-1] + "d.Z" if obs else f.name + ".gz")).write_bytes(packed)
    names = sorted(p.name for p in packed_dir.iterdir())
    assert names == ["07590920.05d.Z", "07590920.05n.gz", "30400920.05d.Z", "30400920.05n.gz"]
    results = {}
    for folder, base in ((plain_dir, "30400920.05o"), (packed_dir, "30400920.05d.Z")):
        r = runner.invoke(
            app,
            ["recording", "init", str(folder), "--base", base,
             "--base-position=-3978241.958,3382840.234,3649900.853",
             "--truth=0759=-3976219.188,3382371.604,3652511.141"],
        )  # fmt: skip
        assert r.exit_code == 0, r.output
        ev = evaluate(open_recording(folder), ["non-cp", "rtklib"], [0.0], None)
        results[folder.name] = {m: (st["0759"].h_rmse_m, st["0759"].v_rmse_m) for m, st in ev.stats.items()}
    assert results["packed"] == results["plain"]
    assert set(results["packed"]) == {"non-cp", "rtklib"}


@pytest.mark.parametrize("fmt", ["ubx", "rtcm3"])
def test_archived_receiver_logs_read_as_the_plain_ones(tmp_path: Path, fmt: str) -> None:
    """`rover.ubx.gz`, `base.rtcm3.gz`: a recording of archived logs opens and reads as the plain one."""
    source = simulate("urban-loop", tmp_path / "sim", vehicles=2, duration_s=10, seed=4)
    plain = tmp_path / fmt
    convert_recording(source, fmt, plain)  # type: ignore[arg-type]  # the parametrised Format
    packed = tmp_path / f"{fmt}-gz"
    shutil.copytree(plain, packed, ignore=shutil.ignore_patterns("fleet.toml"))
    for log in [*packed.rglob("*.ubx"), *packed.rglob("*.rtcm3")]:
        log.with_name(log.name + ".gz").write_bytes(gzip.compress(log.read_bytes()))
        log.unlink()
    plain_rec = open_recording(plain)
    m = plain_rec.manifest
    assert m.base is not None
    base = Path(m.base.obs.relative_to(m.root).as_posix() + ".gz")
    plan = plan_recording(packed, base=base, base_position=m.base.position_ecef_m)
    packed_rec = open_recording(write_plan(plan))
    assert [v.id for v in packed_rec.manifest.vehicles] == ["u1", "u2"]
    assert packed_rec.vehicle_epochs("u1") == plain_rec.vehicle_epochs("u1")
    assert packed_rec.base_epochs() == plain_rec.base_epochs()
    # the same ephemerides (every log with some is merged, so a record may come from another log)
    toes = {sat: [e.toe for e in ephs] for sat, ephs in plain_rec.nav.ephemerides.items()}
    assert {sat: [e.toe for e in ephs] for sat, ephs in packed_rec.nav.ephemerides.items()} == toes
