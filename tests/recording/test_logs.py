"""A receiver log that is both a vehicle's observations and a navigation source is read once.

u-blox and RTCM 3 logs usually carry both. Read twice, a long log cost two parses and its damage
was counted twice; `coplane.recording.logs` reads it once for the recording and for
`coplane recording init`.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import pytest

import coplane.recording.logs as logs
from coplane.recording.convert import convert_recording
from coplane.recording.plan import plan_recording
from coplane.recording.problems import Problems
from coplane.recording.reader import open_recording
from coplane.sim.generate import simulate

JUNK = bytes(range(0x80, 0xA0))  # not ASCII, so not NMEA text: damage


@pytest.fixture
def parses(monkeypatch: pytest.MonkeyPatch) -> Counter[str]:
    """How often each log was parsed, by file name."""
    seen: Counter[str] = Counter()
    for name in ("parse_ubx", "parse_rtcm3"):
        real = getattr(logs, name)

        def counted(path, *args, _real=real, **kwargs):  # type: ignore[no-untyped-def]
            seen[Path(path).name] += 1
            return _real(path, *args, **kwargs)

        monkeypatch.setattr(logs, name, counted)
    return seen


@pytest.mark.parametrize("fmt", ["ubx", "rtcm3"])
def test_a_log_with_observations_and_ephemerides_is_read_once(
    tmp_path: Path, fmt: str, parses: Counter[str]
) -> None:
    source = simulate("urban-loop", tmp_path / "sim", vehicles=2, duration_s=20, seed=12)
    out = tmp_path / fmt
    convert_recording(source, fmt, out)  # type: ignore[arg-type]  # the parametrised Format
    separate = open_recording(out)
    want_nav, want_u1 = separate.nav.ephemerides, separate.vehicle_epochs("u1")
    # u1's receiver also logged the ephemerides, with a few damaged bytes between
    log, nav = out / "vehicles" / f"u1.{fmt}", out / "nav" / f"ephemerides.{fmt}"
    log.write_bytes(nav.read_bytes() + JUNK + log.read_bytes())
    nav.unlink()
    manifest = out / "fleet.toml"
    manifest.write_text(manifest.read_text().replace(f'"nav/ephemerides.{fmt}"', f'"vehicles/u1.{fmt}"'))
    parses.clear()
    rec = open_recording(out)
    assert rec.nav.ephemerides == want_nav and rec.vehicle_epochs("u1") == want_u1
    assert parses[f"u1.{fmt}"] == 1
    assert rec.problems.counts == Counter({"garbled-frame": 1}), rec.problems.items

    # `recording init` reads each log once too, for its observations and its ephemerides
    manifest.unlink()
    parses.clear()
    plan = plan_recording(
        out, base=out / "base" / "ref.rtcm3", base_position=separate.manifest.base.position_ecef_m
    )  # type: ignore[union-attr]
    assert parses == Counter({f"u1.{fmt}": 1, f"u2.{fmt}": 1, "ref.rtcm3": 1})
    assert out / "vehicles" / f"u1.{fmt}" in plan.manifest.nav_files
    assert plan.summaries[log.resolve()].problems == 1


def test_a_navigation_only_log_is_not_an_observation_file(tmp_path: Path) -> None:
    """A UBX log without RXM-RAWX gives its ephemerides and, as observations, the reader's error."""
    source = simulate("urban-loop", tmp_path / "sim", vehicles=1, duration_s=5, seed=12)
    convert_recording(source, "ubx", tmp_path / "ubx")
    problems = Problems()
    parsed = logs.parse_log(tmp_path / "ubx" / "nav" / "ephemerides.ubx", problems)
    assert logs.log_navigation(parsed, problems).ephemerides and not problems
    with pytest.raises(Exception, match="no UBX RXM-RAWX message"):
        logs.log_observations(parsed)


def test_a_log_that_cannot_be_read_is_skipped_with_its_reason(tmp_path: Path) -> None:
    source = simulate("urban-loop", tmp_path / "sim", vehicles=1, duration_s=5, seed=12)
    out = tmp_path / "ubx"
    convert_recording(source, "ubx", out)
    (out / "fleet.toml").unlink()
    (out / "vehicles" / "broken.ubx.gz").write_bytes(b"\x1f\x8b" + bytes(range(256)))  # gzip's magic only
    plan = plan_recording(
        out, base=out / "base" / "ref.rtcm3", base_position=(-2169358.1569, 4387163.9326, 4076271.6104)
    )
    assert [v.id for v in plan.manifest.vehicles] == ["u1"]
    assert any(s.startswith("vehicles/broken.ubx.gz: not read (cannot decompress") for s in plan.skipped), (
        plan.skipped
    )
