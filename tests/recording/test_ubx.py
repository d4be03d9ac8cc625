"""UBX RXM-RAWX: write -> read round trips, signal selection, time tags, and garbled logs."""

from __future__ import annotations

import math
import random
import struct
from pathlib import Path

from pyubx2 import GET, UBXMessage

from coplane.gtime import GpsTime
from coplane.recording.model import ObsEpoch, SatObservation
from coplane.recording.problems import Problems
from coplane.recording.rinex_obs import DEFAULT_SIGNALS, SignalCodes, read_obs
from coplane.recording.ubx import leap_seconds, rawx_message, read_ubx, write_ubx

BUNDLED = Path(__file__).resolve().parents[2] / "shared" / "coplane" / "data" / "recordings" / "default"


def _bundled(n: int = 40) -> list[ObsEpoch]:
    return read_obs(BUNDLED / "vehicles" / "u1.obs", Problems())[1][:n]


def _f32(x: float) -> float:
    return struct.unpack("<f", struct.pack("<f", x))[0]


def test_round_trip_doubles_bit_equal(tmp_path: Path) -> None:
    src = _bundled()
    write_ubx(tmp_path / "u1.ubx", src)
    p = Problems()
    header, got = read_ubx(tmp_path / "u1.ubx", p)
    assert not p
    assert header.obs_types == {"G": ("C1C", "D1C", "S1C"), "C": ("C2I", "D2I", "S2I")}
    assert [e.time for e in got] == [e.time for e in src]  # rcvTow is a double: exact
    for a, b in zip(src, got, strict=True):
        assert [s.sat for s in a.sats] == [s.sat for s in b.sats]
        for s, t in zip(a.sats, b.sats, strict=True):
            assert t.pseudorange_m == s.pseudorange_m  # prMes R8: bit-equal
            assert t.doppler_hz == _f32(s.doppler_hz)  # doMes R4: float32 rounding, nothing else
            assert abs(t.doppler_hz - s.doppler_hz) <= 2.5e-4
            assert t.cn0_dbhz == round(s.cn0_dbhz)  # cno U1: whole dB-Hz


def test_carrier_missing_values_and_flag(tmp_path: Path) -> None:
    t0 = GpsTime(2320, 115200.0039704)
    eps = [
        ObsEpoch(t0, (SatObservation("G05", 2.1e7 + 0.123456789, -1000.5, 45.0, 1.1e8 + 0.25),)),
        ObsEpoch(t0 + 1.0, (SatObservation("C12", 3.8e7, math.nan, math.nan, math.nan),), flag=1),
        ObsEpoch(t0 + 2.0, ()),  # an underpass: no satellites, still an epoch
    ]
    sig = {"G": SignalCodes("C1C", "D1C", "S1C", "L1C"), "C": SignalCodes("C2I", "D2I", "S2I", "L2I")}
    write_ubx(tmp_path / "x.ubx", eps, sig)
    _, got = read_ubx(tmp_path / "x.ubx", Problems(), sig)
    assert [e.flag for e in got] == [0, 1, 0]
    g, c = got[0].sats[0], got[1].sats[0]
    assert g.carrier_cycles == 1.1e8 + 0.25 and g.pseudorange_m == 2.1e7 + 0.123456789
    assert math.isnan(c.doppler_hz) and math.isnan(c.cn0_dbhz) and math.isnan(c.carrier_cycles)
    assert got[2].sats == ()
    # without a carrier code (the default) the phase is not read, as in the RINEX reader
    _, plain = read_ubx(tmp_path / "x.ubx", Problems())
    assert math.isnan(plain[0].sats[0].carrier_cycles)


def _rawx(tow: float, week: int, meas: list[tuple[int, int, int, float]]) -> bytes:
    """A RAWX with (gnssId, svId, sigId, prMes) measurements, as a receiver sends it."""
    kw: dict[str, float | int] = {"rcvTow": tow, "week": week, "leapS": 18, "numMeas": len(meas)}
    for i, (g, sv, sig, pr) in enumerate(meas, start=1):
        k = f"_{i:02d}"
        kw |= {f"gnssId{k}": g, f"svId{k}": sv, f"sigId{k}": sig, f"prMes{k}": pr, f"prValid{k}": 1}
        kw |= {f"cno{k}": 40, f"doMes{k}": 100.0}
    return UBXMessage("RXM", "RXM-RAWX", GET, **kw).serialize()


def test_signal_selection_beidou_geo_and_other_signals(tmp_path: Path) -> None:
    meas = [
        (0, 5, 0, 2.1e7),  # GPS L1 C/A
        (0, 5, 3, 2.1e7 + 5),  # GPS L2 CL: another signal, not the selected one
        (3, 1, 1, 3.9e7),  # BeiDou B1I D2 (GEO C01)
        (3, 20, 0, 2.3e7),  # BeiDou B1I D1
        (2, 7, 0, 2.4e7),  # Galileo: not read
        (0, 6, 0, 1.0e3),  # absurd pseudorange: counted, dropped
    ]
    (tmp_path / "s.ubx").write_bytes(_rawx(100.0, 2320, meas))
    p = Problems()
    _, got = read_ubx(tmp_path / "s.ubx", p)
    assert [s.sat for s in got[0].sats] == ["G05", "C01", "C20"]
    assert got[0].sats[0].pseudorange_m == 2.1e7
    assert p.counts == {"absurd-value": 1}
    sig = {"G": SignalCodes("C2L", "D2L", "S2L"), "C": SignalCodes("C2I")}
    _, l2 = read_ubx(tmp_path / "s.ubx", Problems(), sig)
    assert l2[0].sats[0].pseudorange_m == 2.1e7 + 5


def test_week_from_receiver_and_leap_seconds(tmp_path: Path) -> None:
    # rcvTow/week are the receiver's full GPST tag: a week rollover is just the next week
    data = _rawx(604799.5, 2320, [(0, 5, 0, 2.1e7)]) + _rawx(0.5, 2321, [(0, 5, 0, 2.1e7)])
    (tmp_path / "w.ubx").write_bytes(data)
    p = Problems()
    _, got = read_ubx(tmp_path / "w.ubx", p)
    assert [e.time for e in got] == [GpsTime(2320, 604799.5), GpsTime(2321, 0.5)]
    assert got[1].time - got[0].time == 1.0 and not p
    # GPS - UTC steps (IERS bulletin C): 17 s until 2017-01-01 00:00:17 GPST, 18 s after
    step = GpsTime.from_calendar(2017, 1, 1, 0, 0, 17)
    assert leap_seconds(step + -1e-3) == 17 and leap_seconds(step) == 18
    assert leap_seconds(GpsTime.from_calendar(1998, 6, 1)) is None
    assert rawx_message(ObsEpoch(GpsTime(2320, 0.0), ()), {}).leapS == 18


def test_hostile_log_counts_damage_and_keeps_good_frames(tmp_path: Path) -> None:
    rng = random.Random(7)
    t0 = GpsTime(2320, 115200.0)
    src = [
        ObsEpoch(
            t0 + k, tuple(SatObservation(f"G{n:02d}", 2.1e7 + 1e3 * k + n, -500.0, 40.0) for n in (5, 7, 9))
        )
        for k in range(900)
    ]
    frames = [rawx_message(e, DEFAULT_SIGNALS).serialize() for e in src]
    out = bytearray()
    damaged = set()
    for i, fr in enumerate(frames):
        b = bytearray(fr)
        kind = rng.random()
        if kind < 0.25:  # a flipped bit anywhere (header, length, payload, checksum)
            j = rng.randrange(len(b))
            b[j] ^= 1 << rng.randrange(8)
            damaged.add(i)
        elif kind < 0.35:  # truncated frame
            b = b[: rng.randrange(1, len(b) - 1)]
            damaged.add(i)
        elif kind < 0.45:  # junk before the frame, with false sync bytes in it
            out += bytes(rng.randrange(256) for _ in range(rng.randrange(1, 40))) + b"\xb5\x62\xff\xff"
        out += b
        if kind > 0.95:  # NMEA text between frames: another protocol, not damage
            out += b"$GNGGA,083000.00,3959.0,N,11618.0,E,1,12,0.9,50.0,M,-8.0,M,,*4F\r\n"
    (tmp_path / "bad.ubx").write_bytes(bytes(out))
    p = Problems()
    _, got = read_ubx(tmp_path / "bad.ubx", p)
    assert len(damaged) > 250
    kept = [src[i].time for i in range(len(src)) if i not in damaged]
    assert [e.time for e in got] == kept  # every undamaged frame is read, none invented
    assert p.counts["garbled-frame"] >= len(damaged) * 0.5  # adjacent damage may merge into one run
    first = p.items[0]
    assert first.offset is not None and f"bad.ubx:byte {first.offset}:" in str(first)
