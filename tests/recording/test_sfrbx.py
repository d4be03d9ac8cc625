"""RXM-SFRBX: GPS LNAV and BeiDou D1/D2 subframes re-encoded from RINEX ephemerides and decoded
back within the ICD LSBs; ionosphere; parity; the 10-bit GPS week."""

from __future__ import annotations

from pathlib import Path

from pyubx2 import UBXReader

from coplane.gtime import GpsTime
from coplane.recording.model import IonoCoefficients, NavData
from coplane.recording.problems import Problems
from coplane.recording.rinex_nav import read_nav
from coplane.recording.sfrbx import ephemeris_messages, lsb, read_sfrbx_nav, write_sfrbx_nav
from coplane.recording.sfrbx_bds import FIELDS, ION_LSB, is_geo

NAV = (
    Path(__file__).resolve().parents[2]
    / "shared"
    / "coplane"
    / "data"
    / "recordings"
    / "default"
    / "nav"
    / "brdc.rnx"
)
ORBIT = ("af0", "af1", "af2", "crs", "delta_n", "m0", "cuc", "e", "cus", "sqrt_a", "cic", "omega0", "cis", "i0",
         "crc", "omega", "omega_dot", "idot", "tgd")  # fmt: skip


def _nav() -> NavData:
    return read_nav(NAV, Problems())


def test_gps_and_beidou_d1_d2_round_trip_within_lsb(tmp_path: Path) -> None:
    nav = _nav()
    nav.iono["C"] = IonoCoefficients(
        (1.21e-08, 1.49e-07, -1.07e-06, 1.19e-06), (110592.0, 114688.0, -393216.0, 262144.0)
    )
    assert write_sfrbx_nav(tmp_path / "n.ubx", nav) == []
    p = Problems()
    back = read_sfrbx_nav(tmp_path / "n.ubx", p, reference=GpsTime(2320, 0.0))
    assert not p
    assert set(back.ephemerides) == set(nav.ephemerides)  # all 13 GPS and 32 BeiDou, GEO included
    assert any(is_geo(int(s[1:])) for s in back.ephemerides if s[0] == "C")
    for sat, ephs in nav.ephemerides.items():
        for a, b in zip(ephs, back.ephemerides[sat], strict=True):
            assert (a.toe, a.toc, a.week, a.iode, a.iodc, a.health) == (
                b.toe,
                b.toc,
                b.week,
                b.iode,
                b.iodc,
                b.health,
            )
            for attr in ORBIT:
                q = lsb(attr) if sat[0] == "G" else FIELDS[attr].lsb
                assert abs(getattr(a, attr) - getattr(b, attr)) <= q / 2, (sat, attr)
            if sat[0] == "C":
                assert abs(a.tgd2 - b.tgd2) <= FIELDS["tgd2"].lsb / 2
    # Klobuchar: GPS page 18 and BeiDou D1 subframe 1, to their 8-bit LSBs
    for sys in ("G", "C"):
        for x, y, q in zip(
            (*nav.iono[sys].alpha, *nav.iono[sys].beta),
            (*back.iono[sys].alpha, *back.iono[sys].beta),
            ION_LSB,
            strict=True,
        ):
            assert abs(x - y) <= q / 2


def test_subframe_shapes() -> None:
    nav = _nav()
    gps = ephemeris_messages(nav.ephemerides["G05"][0])
    meo = ephemeris_messages(nav.ephemerides["C20"][0])
    geo = ephemeris_messages(nav.ephemerides["C01"][0])
    assert [len(gps), len(meo), len(geo)] == [3, 3, 9]  # LNAV 1-3, D1 1-3, D2 pages 1 and 3-10
    parsed = UBXReader.parse(geo[0].serialize())
    assert (parsed.gnssId, parsed.svId, parsed.sigId, parsed.numWords) == (3, 1, 1, 10)  # B1I D2
    first = UBXReader.parse(gps[0].serialize()).dwrd_01
    assert first >> 22 == 0x8B  # TLM preamble in the 30-bit word's top 8 bits


def test_bad_parity_is_reported_and_ephemeris_not_invented(tmp_path: Path) -> None:
    nav = _nav()
    e = nav.ephemerides["G05"][0]
    msgs = ephemeris_messages(e)
    raw = bytearray(msgs[1].serialize())
    raw[6 + 8 + 4 * 4 + 1] ^= 0x10  # one data bit of word 5 of subframe 2 ...
    from pyubx2.ubxhelpers import calc_checksum

    raw[-2:] = calc_checksum(bytes(raw[2:-2]))  # ... behind a valid UBX checksum
    (tmp_path / "p.ubx").write_bytes(msgs[0].serialize() + bytes(raw) + msgs[2].serialize())
    p = Problems()
    back = read_sfrbx_nav(tmp_path / "p.ubx", p, reference=GpsTime(2320, 0.0))
    assert p.counts == {"malformed-record": 1} and not back.ephemerides
    assert "p.ubx:byte " in str(p.items[0])


def test_ten_bit_week_resolved_against_reference(tmp_path: Path) -> None:
    nav = NavData()
    e = _nav().ephemerides["G05"][0]
    nav.add(e)
    write_sfrbx_nav(tmp_path / "w.ubx", nav)
    now = read_sfrbx_nav(tmp_path / "w.ubx", Problems(), reference=GpsTime(e.week + 400, 0.0))
    assert now.ephemerides["G05"][0].toe == e.toe
    old = read_sfrbx_nav(tmp_path / "w.ubx", Problems(), reference=GpsTime(e.week - 1000, 0.0))
    assert old.ephemerides["G05"][0].toe == GpsTime(e.toe.week - 1024, e.toe.tow)


def test_garbled_nav_file_counts_damage_and_keeps_the_rest(tmp_path: Path) -> None:
    nav = _nav()
    write_sfrbx_nav(tmp_path / "n.ubx", nav)
    data = bytearray((tmp_path / "n.ubx").read_bytes())
    data[40:44] = b"\x00\xff\x00\xff"  # inside the first frame (page 18): its checksum fails
    (tmp_path / "n.ubx").write_bytes(bytes(data))
    p = Problems()
    back = read_sfrbx_nav(tmp_path / "n.ubx", p, reference=GpsTime(2320, 0.0))
    assert p.counts == {"garbled-frame": 1} and p.items[0].offset == 0
    assert "G" not in back.iono and set(back.ephemerides) == set(nav.ephemerides)
