"""RINEX navigation reader on the hand-made corpus: clean file against RTKLIB, broken file against clean.

clean_nav.rnx mixes G and C records with R/S (4-line) and E/J/I (8-line) records that must be
skipped; broken_nav.rnx has a 7-line G record, an unreadable number, a garbage line, an absurd
sqrt(A) and a broken BDSB header line.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from support.rtklib_rinex_ref import all_ephemerides, compare_nav_to_rtklib

from coplane.gtime import gpst_to_bdt
from coplane.recording.problems import Problems, RecordingError
from coplane.recording.rinex_nav import read_nav, read_nav_files

BROKEN = Path(__file__).resolve().parents[1] / "data" / "broken"


def test_clean_nav_matches_rtklib() -> None:
    problems = Problems()
    nav = read_nav(BROKEN / "clean_nav.rnx", problems)
    assert problems.total == 0
    assert nav.satellites == ["C01", "C14", "C59", "G05", "G06", "G13"]  # R, S, E, J, I skipped
    assert compare_nav_to_rtklib(BROKEN / "clean_nav.rnx", nav) == 6


def test_broken_nav_keeps_the_valid_records() -> None:
    clean = all_ephemerides(read_nav(BROKEN / "clean_nav.rnx", Problems()))
    problems = Problems()
    nav = read_nav(BROKEN / "broken_nav.rnx", problems)
    assert [(p.kind, p.line) for p in problems.items] == [
        ("header", 7),  # BDSB garbage: BeiDou ionosphere not used
        ("malformed-record", 10),  # G05 lost its last line
        ("unexpected-line", 37),  # garbage between records
        ("malformed-record", 38),  # C01 unreadable number
        ("absurd-value", 74),  # G13 with sqrt(A) = 0
    ]
    got = all_ephemerides(nav)
    assert got == {k: v for k, v in clean.items() if k[0] in ("G06", "C14", "C59")}
    assert "C" not in nav.iono and "G" in nav.iono


def test_beidou_times_are_converted_to_gpst() -> None:
    nav = read_nav(BROKEN / "clean_nav.rnx", Problems())
    c01 = nav.ephemerides["C01"][0]
    # epoch line "C01 2024 06 24 08 00 00" is BDT; GPST is 14 s later; toe SOW 115200 BDT
    assert c01.toc.to_calendar() == (2024, 6, 24, 8, 0, 14.0)
    assert gpst_to_bdt(c01.toe) == (964, 115200.0)
    assert c01.week == 964


def test_read_nav_files_merges_and_drops_duplicates() -> None:
    one = read_nav(BROKEN / "clean_nav.rnx", Problems())
    both = read_nav_files([BROKEN / "clean_nav.rnx", BROKEN / "broken_nav.rnx"], Problems())
    assert all_ephemerides(both) == all_ephemerides(one)
    assert both.iono == one.iono


@pytest.mark.parametrize("name", ["clean_v3.obs", "does_not_exist.rnx", "not_rinex.obs"])
def test_unusable_nav_file_raises(name: str) -> None:
    with pytest.raises(RecordingError, match=name.replace(".", r"\.")):
        read_nav(BROKEN / name, Problems())


STATUS_LINE = "     .000000000000D+00 .000000000000D+00 .000000000000D+00 .000000000000D+00"


def test_rinex_305_glonass_records_are_skipped_whole(real_data: Path, tmp_path: Path) -> None:
    """RINEX 3.05 (e.g. a day's merged broadcast file) gives each GLONASS record a fifth line:
    skipped with its record, no problem counted, the GPS and BeiDou ephemerides as in 3.04."""
    src = real_data / "matrtklib_nagoya_static_20240624" / "base.nav"
    lines = src.read_text().splitlines()
    out, k = [], 0
    while k < len(lines):
        line = lines[k]
        if k == 0:
            line = "     3.05" + line[9:]
        out.append(line)
        if line.startswith("R") and line[1:3].isdigit():
            out += [*lines[k + 1 : k + 4], STATUS_LINE]
            k += 4
            continue
        k += 1
    assert sum(1 for x in out if x.startswith("R")) > 5
    v305 = tmp_path / "base305.nav"
    v305.write_text("\n".join(out) + "\n")
    want, got = Problems(), Problems()
    nav304, nav305 = read_nav(src, want), read_nav(v305, got)
    assert not want and not got
    assert nav305.ephemerides == nav304.ephemerides
