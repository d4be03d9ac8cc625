"""RTCM 3: MSM7/MSM4 and 1019/1042 round trips within the stated LSBs, time and week handling,
and garbled streams."""

from __future__ import annotations

import math
import random
from pathlib import Path
from types import SimpleNamespace

import pytest
from pyrtcm import RTCMReader

from coplane.gtime import GpsTime, bdt_to_gpst
from coplane.recording.broadcast import nearest_week, resolve_week
from coplane.recording.model import Ephemeris, NavData, ObsEpoch, SatObservation
from coplane.recording.problems import Problems
from coplane.recording.rinex_nav import read_nav
from coplane.recording.rinex_obs import DEFAULT_SIGNALS, SignalCodes, read_obs
from coplane.recording.rtcm3 import (
    C_LIGHT,
    CNR_LSB_DBHZ,
    FREQ_HZ,
    LIGHT_MS,
    PSEUDORANGE_LSB_M,
    RtcmReader,
    lock_indicator,
    msm_frames,
    read_rtcm3,
    read_rtcm3_nav,
    write_rtcm3,
)
from coplane.recording.rtcm3_ephemeris import decode_ephemeris, ephemeris_frame, ephemeris_lsb
from coplane.recording.rtcm_encode import FieldRangeError, build_frame

DEFAULT = Path(__file__).resolve().parents[2] / "shared" / "coplane" / "data" / "recordings" / "default"
DOPPLER_TOL_HZ = 0.5e-4 / (C_LIGHT / FREQ_HZ["G"]) + 1e-9  # half the 0.0001 m/s LSB, on L1 (2.6e-4 Hz)


def _nav() -> NavData:
    return read_nav(DEFAULT / "nav" / "brdc.rnx", Problems())


def _moved(s: SatObservation, d: float) -> float:
    """The pseudorange carried from the source tag to the MSM tag along its Doppler."""
    return s.pseudorange_m + d * C_LIGHT / FREQ_HZ[s.sat[0]] * (
        s.doppler_hz if math.isfinite(s.doppler_hz) else 0.0
    )


def test_msm7_round_trip_within_lsb(tmp_path: Path) -> None:
    src = read_obs(DEFAULT / "vehicles" / "u1.obs", Problems())[1][:60]
    rep = write_rtcm3(tmp_path / "u1.rtcm3", src, _nav())
    assert rep.epochs == 60 and not rep.skipped
    p = Problems()
    _, got = read_rtcm3(tmp_path / "u1.rtcm3", p)
    assert not p and len(got) == len(src)
    worst_pr = 0.0
    for a, b in zip(src, got, strict=True):
        d = a.time - b.time
        assert abs(d) <= 0.5e-3 and round(b.time.tow * 1000) == b.time.tow * 1000  # whole ms
        bs = b.by_sat()
        assert set(bs) == {s.sat for s in a.sats}
        for s in a.sats:
            t = bs[s.sat]
            worst_pr = max(worst_pr, abs(t.pseudorange_m - _moved(s, d)))
            assert abs(t.doppler_hz - s.doppler_hz) <= DOPPLER_TOL_HZ
            assert abs(t.cn0_dbhz - s.cn0_dbhz) <= CNR_LSB_DBHZ / 2 + 1e-9
    assert worst_pr <= PSEUDORANGE_LSB_M / 2 + 1e-9  # 0.279 mm
    print(f"MSM7 round trip: largest pseudorange difference {worst_pr * 1e3:.3f} mm (LSB 0.558 mm)")


def test_msm7_carrier_and_msm4(tmp_path: Path) -> None:
    t = GpsTime(2320, 115200.0)  # whole ms: nothing to move
    lam = C_LIGHT / FREQ_HZ["G"]
    pr = 2.2e7 + 0.4321
    eps = [ObsEpoch(t, (SatObservation("G05", pr, -1234.567, 44.3, (pr + 3.0) / lam),))]
    sig = {"G": SignalCodes("C1C", "D1C", "S1C", "L1C"), "C": SignalCodes("C2I", "D2I", "S2I", "L2I")}
    write_rtcm3(tmp_path / "a.rtcm3", eps, signals=sig)
    s7 = read_rtcm3(tmp_path / "a.rtcm3", Problems(), sig)[1][0].sats[0]
    assert abs(s7.carrier_cycles * lam - (pr + 3.0)) <= 2.0**-31 * C_LIGHT * 1e-3 / 2 + 1e-9  # 0.07 mm
    write_rtcm3(tmp_path / "b.rtcm3", eps, signals=sig, msm=4)
    p = Problems()
    frames = (tmp_path / "b.rtcm3").read_bytes()
    assert RTCMReader.parse(frames).identity == "1074"
    s4 = read_rtcm3(tmp_path / "b.rtcm3", p, sig)[1][0].sats[0]
    assert abs(s4.pseudorange_m - pr) <= 2.0**-24 * C_LIGHT * 1e-3 / 2  # MSM4: 17.9 mm LSB
    assert math.isnan(s4.doppler_hz) and s4.cn0_dbhz == 44.0  # no Doppler in MSM4; 1 dB-Hz C/N0
    assert abs(s4.carrier_cycles * lam - (pr + 3.0)) <= 2.0**-29 * C_LIGHT * 1e-3 / 2 + 1e-9


@pytest.mark.parametrize("msm", [4, 5, 6, 7])
def test_every_msm_level_in_and_out(tmp_path: Path, msm: int) -> None:
    """MSM4-7, GPS and BeiDou: a base station's stream may be any (casters choose by bandwidth).
    MSM6/7 carry the extended resolution, MSM5/7 the phase-range rates (Doppler)."""
    t = GpsTime(2320, 115200.0)
    sats = (SatObservation("G05", 2.2e7 + 0.4321, -1234.567, 44.3, math.nan),)
    sats += (SatObservation("C12", 2.3e7 + 0.1234, 987.654, 38.6, math.nan),)
    write_rtcm3(tmp_path / "m.rtcm3", [ObsEpoch(t, sats)], msm=msm)
    data = (tmp_path / "m.rtcm3").read_bytes()
    assert RTCMReader.parse(data).identity == f"107{msm}"
    p = Problems()
    got = read_rtcm3(tmp_path / "m.rtcm3", p, reference=t)[1][0].by_sat()
    assert not p and set(got) == {"G05", "C12"}
    extended, rates = msm in (6, 7), msm in (5, 7)
    for s in sats:
        g = got[s.sat]
        lam = C_LIGHT / FREQ_HZ[s.sat[0]]
        assert (
            abs(g.pseudorange_m - s.pseudorange_m)
            <= (2.0**-29 if extended else 2.0**-24) * LIGHT_MS / 2 + 1e-9
        )
        assert abs(g.cn0_dbhz - s.cn0_dbhz) <= (CNR_LSB_DBHZ if extended else 1.0) / 2 + 1e-9
        if rates:
            assert abs(g.doppler_hz - s.doppler_hz) <= 0.5e-4 / lam + 1e-9
        else:
            assert math.isnan(g.doppler_hz)
    with pytest.raises(ValueError, match="MSM3: coplane writes MSM4 to MSM7"):
        write_rtcm3(tmp_path / "x.rtcm3", [ObsEpoch(t, sats)], msm=3)


def test_ephemerides_1019_1042_within_lsb(tmp_path: Path) -> None:
    nav = _nav()
    write_rtcm3(tmp_path / "n.rtcm3", [], nav)
    p = Problems()
    back = read_rtcm3_nav(tmp_path / "n.rtcm3", p)
    assert not p and set(back.ephemerides) == set(nav.ephemerides)
    assert any(s in back.ephemerides for s in ("C01", "C02", "C03"))  # GEO (D2) too: 1042 has them
    for sat, ephs in nav.ephemerides.items():
        lsb = ephemeris_lsb(sat[0])
        for a, b in zip(ephs, back.ephemerides[sat], strict=True):
            assert (a.toe, a.toc, a.week, a.iode, a.health) == (b.toe, b.toc, b.week, b.iode, b.health)
            for attr, q in lsb.items():
                assert abs(getattr(a, attr) - getattr(b, attr)) <= q / 2, (sat, attr)


def test_week_rollover_rules() -> None:
    # 10-bit GPS week (1019): the 1024-week cycle nearest the reference
    assert resolve_week(0, 10, 1023) == 1024
    assert resolve_week(1023, 10, 1024) == 1023
    assert resolve_week(2320 % 1024, 10, 2320) == 2320
    assert resolve_week(2320 % 1024, 10, 2320 - 511) == 2320
    assert resolve_week(2320 % 1024, 10, 2320 - 513) == 2320 - 1024
    # MSM time of week: the instant nearest the reference, across the week boundary both ways
    assert nearest_week(0.5, GpsTime(2320, 604799.0)) == GpsTime(2321, 0.5)
    assert nearest_week(604799.5, GpsTime(2321, 1.0)) == GpsTime(2320, 604799.5)
    assert nearest_week(1000.0, GpsTime(2320, 0.0)) == GpsTime(2320, 1000.0)


def test_1019_week_resolved_against_reference() -> None:
    e = _nav().ephemerides["G05"][0]
    msg = RTCMReader.parse(ephemeris_frame(e))
    assert e.week % 1024 == msg.DF076
    assert decode_ephemeris(msg, GpsTime(e.week, 0.0)).toe == e.toe
    old = decode_ephemeris(msg, GpsTime(e.week - 1024, 0.0))  # a 2004 log: one cycle back
    assert old.toe == GpsTime(e.toe.week - 1024, e.toe.tow)


def test_epochs_across_gps_and_bdt_week_ends(tmp_path: Path) -> None:
    """GPST 2320:604799 .. 2321:2 with BeiDou: the BDT week ends 14 s later than GPST's."""
    sats = (SatObservation("G05", 2.2e7, 10.0, 40.0), SatObservation("C20", 2.3e7, 20.0, 40.0))
    times = [GpsTime(2320, 604799.0), GpsTime(2321, 0.0), GpsTime(2321, 1.0), GpsTime(2321, 14.0)]
    write_rtcm3(tmp_path / "w.rtcm3", [ObsEpoch(t, sats) for t in times])
    p = Problems()
    _, got = read_rtcm3(tmp_path / "w.rtcm3", p, reference=GpsTime(2320, 600000.0))
    assert not p
    assert [e.time for e in got] == times
    assert all([s.sat for s in e.sats] == ["G05", "C20"] for e in got)
    # without a reference, the file's 1042 (13-bit BDT week: no rollover until 2163) places it
    nav = NavData()
    e = _nav().ephemerides["C20"][0]
    nav.add(e)
    near = [e.toe + 0.5 + k for k in range(3)]
    write_rtcm3(tmp_path / "e.rtcm3", [ObsEpoch(t, sats) for t in near], nav)
    assert [x.time for x in read_rtcm3(tmp_path / "e.rtcm3", Problems())[1]] == near
    assert bdt_to_gpst(e.week, 0.0).week == e.week + 1356


def test_lock_indicator_table() -> None:
    # RTCM 10403.3 DF407: exact below 64 ms, then steps doubling every 32 indices
    assert [lock_indicator(x) for x in (0, 63, 64, 65, 66, 128, 130, 256)] == [0, 63, 64, 64, 65, 96, 96, 128]
    assert lock_indicator(10**9) == 704


def test_encoder_checks_ranges() -> None:
    with pytest.raises(FieldRangeError):
        build_frame("1019", {"DF009": 64})
    with pytest.raises(FieldRangeError):
        build_frame("1019", {"DF088": 2**31})
    eph = _nav().ephemerides["G05"][0]
    bad = Ephemeris(**{**{f: getattr(eph, f) for f in eph.__slots__}, "crs": 1e6})  # type: ignore[attr-defined]
    with pytest.raises(FieldRangeError):
        ephemeris_frame(bad)


def test_hostile_stream_counts_damage_and_keeps_good_frames(tmp_path: Path) -> None:
    rng = random.Random(11)
    t0 = GpsTime(2320, 115200.0)
    src = [
        ObsEpoch(
            t0 + k, tuple(SatObservation(f"G{n:02d}", 2.1e7 + 1e3 * k + n, -500.0, 40.0) for n in (5, 7, 9))
        )
        for k in range(900)
    ]
    frames = [msm_frames(e, DEFAULT_SIGNALS)[0] for e in src]
    out = bytearray()
    damaged = set()
    for i, fr in enumerate(frames):
        b = bytearray(fr)
        kind = rng.random()
        if kind < 0.25:
            j = rng.randrange(len(b))
            b[j] ^= 1 << rng.randrange(8)
            damaged.add(i)
        elif kind < 0.35:
            b = b[: rng.randrange(1, len(b) - 1)]
            damaged.add(i)
        elif kind < 0.45:
            out += bytes(rng.randrange(256) for _ in range(rng.randrange(1, 40))) + b"\xd3\x00\x13"
        out += b
    (tmp_path / "bad.rtcm3").write_bytes(bytes(out))
    p = Problems()
    _, got = read_rtcm3(tmp_path / "bad.rtcm3", p, reference=t0)
    assert len(damaged) > 250
    assert [e.time for e in got] == [src[i].time for i in range(len(src)) if i not in damaged]
    assert p.counts["garbled-frame"] >= len(damaged) * 0.5
    assert "bad.rtcm3:byte " in str(p.items[0])


def test_the_week_reference_is_the_median_toe_and_skips_what_does_not_make_one() -> None:
    """MSM has no week, so a log's epochs are placed near a reference from its ephemerides: the
    median of the 1042s' toes, so that a stray one of another week moves nothing, and a message
    whose fields make no toe (a damaged one) is skipped there, not raised (it is named when the
    ephemerides are decoded)."""
    rd = RtcmReader("x.rtcm3", Problems(), dict(DEFAULT_SIGNALS), ("G", "C"))

    def b1042(week: int, toe: float) -> tuple[int, SimpleNamespace]:
        return 0, SimpleNamespace(identity="1042", DF489=week, DF505=toe)

    good = [b1042(805, 3600.0 * h) for h in range(5)]  # BDT week 805 = GPS week 2161
    stray = b1042(775, 0.0)  # 30 weeks older, first in the log
    broken = (0, SimpleNamespace(identity="1042"))  # no fields
    assert rd.reference([stray, *good, broken], None) == bdt_to_gpst(805, 3600.0)  # the lower median of 6
    assert rd.reference([broken], None).week >= 2161  # nothing usable: today
