"""RINEX 4 navigation files (what IGS broadcast files such as BRD400DLR are today) and observation files.

No RINEX 4 file is among the real sets, so a real RINEX 3.04 navigation file (Nagoya, mixed
G/R/E/C/J) is written here as RINEX 4.00 lays the same records out: a `> EPH sat message` line
before each record, the header's ionosphere as Klobuchar `ION` records, GLONASS records one line
longer, lower-case exponents, and the records a reader must skip (GPS CNAV, STO, EOP, NeQuick).
It must read back to the same ephemerides and ionosphere.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from coplane.recording.discover import sniff
from coplane.recording.model import IonoCoefficients
from coplane.recording.problems import Problems, RecordingError
from coplane.recording.rinex_nav import read_nav
from coplane.recording.rinex_obs import read_obs

NAGOYA = "matrtklib_nagoya_static_20240624"
_START = re.compile(r"^[A-Z][ 0-9]\d \d{4} ")
_MESSAGE = {"G": "LNAV", "J": "LNAV", "E": "INAV", "R": "FDMA", "S": "SBAS", "I": "LNAV"}
_BDS_GEO = {1, 2, 3, 4, 5, 59, 60, 61, 62, 63}  # BeiDou GEO satellites broadcast D2


def _v(*values: float) -> str:
    return "".join(f"{x:19.12e}" for x in values)


# what a RINEX 4 reader must skip: another message of a wanted system, and the other record types
_SKIPPED = [
    "> EPH G05 CNAV",
    "G05 2024 06 24 09 30 00" + _v(-1.77e-04, -1.36e-12, 0.0),
    *["    " + _v(1.0, 2.0, 3.0, 4.0)] * 8,
    "> STO G05 LNAV",
    "    2024 06 24 09 00 00 GPUT",
    "    " + _v(319488.0, -9.3132257462e-10, -7.99e-15, 0.0),
    "> EOP G05 CNVX",
    "    2024 06 24 09 00 00" + _v(0.1, 1e-4, 0.0),
    "    " + _v(0.2, 1e-4, 0.0),
    "    " + _v(319488.0, 0.1, 1e-4, 0.0),
    "> ION E11 IFNV",
    "    2024 06 24 09 00 00" + _v(161.75, 0.66016, 0.019379),
    "    " + _v(0.0),
]
BDS_KLOBUCHAR = IonoCoefficients((1.1e-08, 2.2e-08, -3.3e-08, 4.4e-08), (1.2e05, 2.3e05, -3.4e05, 4.5e05))


def rinex4_nav(v3: str) -> str:
    """A RINEX 3 navigation file's content as RINEX 4.00 writes it."""
    lines = v3.splitlines()
    end = next(i for i, x in enumerate(lines) if "END OF HEADER" in x)
    header = [x for x in lines[1:end] if x[60:].strip() not in ("IONOSPHERIC CORR", "TIME SYSTEM CORR")]
    iono = {
        x[0:4]: [float(x[5 + 12 * k : 17 + 12 * k].replace("D", "E")) for k in range(4)]
        for x in lines[1:end]
        if "IONOSPHERIC CORR" in x and x[0:4] in ("GPSA", "GPSB")
    }
    out = [
        "     4.00           N: GNSS NAV DATA    M: MIXED            RINEX VERSION / TYPE",
        *header,
        lines[end],
    ]
    a, b = iono["GPSA"], iono["GPSB"]
    out += [
        "> ION G05 LNAV",
        "    2024 06 24 09 00 00" + _v(*a[:3]),
        "    " + _v(a[3], *b[:3]),
        "    " + _v(b[3], 0.0),
    ]
    a, b = list(BDS_KLOBUCHAR.alpha), list(BDS_KLOBUCHAR.beta)
    out += [
        "> ION C20 D1D2",
        "    2024 06 24 09 00 00" + _v(*a[:3]),
        "    " + _v(a[3], *b[:3]),
        "    " + _v(b[3], 1.0),
    ]
    out += _SKIPPED
    body = [re.sub(r"[DE]([+-]\d\d)", r"e\1", x) for x in lines[end + 1 :]]
    for i, line in enumerate(body):
        if _START.match(line):
            sys, prn = line[0], int(line[1:3])
            message = ("D2" if prn in _BDS_GEO else "D1") if sys == "C" else _MESSAGE[sys]
            out.append(f"> EPH {line[0:3]} {message}")
        out.append(line)
        if sys == "R" and (i + 1 == len(body) or _START.match(body[i + 1])):
            out.append("    " + _v(0.0, 0.0, 0.0, 0.0))  # RINEX 4 adds a line to GLONASS FDMA records
    return "\n".join(out) + "\n"


@pytest.fixture
def v3_and_v4(real_data: Path, tmp_path: Path) -> tuple[Path, Path]:
    v3 = real_data / NAGOYA / "base.nav"
    v4 = tmp_path / "BRD400DLR_S_20241760000_01D_MN.rnx"
    v4.write_text(rinex4_nav(v3.read_text()))
    return v3, v4


def test_a_rinex4_navigation_file_reads_as_its_rinex3_records(v3_and_v4: tuple[Path, Path]) -> None:
    v3, v4 = v3_and_v4
    p3, p4 = Problems(), Problems()
    want, got = read_nav(v3, p3), read_nav(v4, p4)
    assert not p4, p4.items[:3]
    assert got.ephemerides == want.ephemerides and {s[0] for s in got.satellites} == {"G", "C"}
    assert got.iono["G"] == want.iono["G"] and got.iono["C"] == BDS_KLOBUCHAR
    ref = sniff(v4)
    assert ref is not None and (ref.kind, ref.version) == ("nav", 4.0)


def test_broken_rinex4_records_are_counted_and_the_rest_kept(
    v3_and_v4: tuple[Path, Path], tmp_path: Path
) -> None:
    v3, v4 = v3_and_v4
    text = v4.read_text().replace("> ION G05 LNAV\n    2024", "> ION G05 LNAV\n    2024 13", 1)  # no month 13
    lines = text.splitlines()
    head = next(i for i, x in enumerate(lines) if "END OF HEADER" in x)
    lines.insert(head + 1, "stray text before the first record")
    eph = next(i for i, x in enumerate(lines) if x.startswith("> EPH G") and x.endswith("LNAV"))
    lines[eph + 3] = lines[eph + 3][:30]  # a GPS record cut short inside a field
    lines.insert(eph, "> XYZ G01 LNAV")  # an unknown record type, with no body
    lines.insert(eph, "> EPH G02 LNAV")  # a wanted record with no body
    lines[eph:eph] = ["> EPH G03 LNAV", "Gxx 2024 06 24 09 00 00"]  # its first line unreadable
    bad = tmp_path / "bad.rnx"
    bad.write_text("\n".join(lines) + "\n")
    problems = Problems()
    nav = read_nav(bad, problems)
    assert dict(problems.counts) == {"unexpected-line": 1, "malformed-record": 5}, problems.items
    want = read_nav(v3, Problems())
    assert sum(map(len, nav.ephemerides.values())) == sum(map(len, want.ephemerides.values())) - 1
    assert "G" not in nav.iono and nav.iono["C"] == BDS_KLOBUCHAR  # the broken GPS ION record: none
    version5 = tmp_path / "v5.rnx"
    version5.write_text(v4.read_text().replace("     4.00  ", "     5.00  ", 1))
    with pytest.raises(RecordingError, match=r"v5\.rnx:1: RINEX version 5\.0 is not supported"):
        read_nav(version5, Problems())


def test_rinex4_observations_read_as_rinex3(real_data: Path, tmp_path: Path) -> None:
    """RINEX 4 kept RINEX 3.05's observation records; its new header lines are ones coplane skips."""
    v3 = real_data / NAGOYA / "rover.obs"
    text = v3.read_text()
    v4 = tmp_path / "rover.rnx"
    lines = text.splitlines()
    lines[0] = "     4.00" + lines[0][9:]
    lines.insert(2, f"{'coplane test':<60}DOI")
    v4.write_text("\n".join(lines) + "\n")
    want_header, want = read_obs(v3, Problems())
    got_header, got = read_obs(v4, Problems())
    assert got == want and got_header.obs_types == want_header.obs_types
