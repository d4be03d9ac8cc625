"""The stream decoder against the file readers: a receiver stream cut anywhere gives the file's
epochs and ephemerides; garbled, truncated and bit-flipped frames cost only themselves (issue 15,
"10,000 garbled, truncated or bit-flipped UBX and RTCM frames: 0 crashes, every bad frame counted,
and the valid frames around them still used")."""

from __future__ import annotations

import dataclasses
import random
import threading
from pathlib import Path

import pytest

from coplane.gtime import GpsTime
from coplane.live.decode import GnssStreamDecoder
from coplane.live.sources import FileSource
from coplane.recording.convert import convert_recording
from coplane.recording.frames import Frame, rtcm_frames, rtcm_scanner, ubx_frames, ubx_scanner
from coplane.recording.model import NavData
from coplane.recording.problems import Problems
from coplane.recording.rtcm3 import read_rtcm3, read_rtcm3_nav
from coplane.recording.sfrbx import read_sfrbx_nav
from coplane.recording.ubx import read_ubx
from coplane.sim.generate import simulate

FORMATS = ("ubx", "rtcm3")


@pytest.fixture(scope="module")
def logs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """u1's observations (with navigation) as UBX and as RTCM 3 (urban-loop, 2 vehicles, 60 s)."""
    root = tmp_path_factory.mktemp("live-decode")
    simulate("urban-loop", root / "sim", 2, 60, seed=3)
    out = {}
    for fmt in FORMATS:
        convert_recording(root / "sim", fmt, root / fmt)  # type: ignore[arg-type]
        out[fmt] = root / fmt / "vehicles" / f"u1.{fmt}"
    return out


def _reference(fmt: str, path: Path) -> tuple[list, NavData]:
    p = Problems()
    if fmt == "ubx":
        _, epochs = read_ubx(path, p)
        return epochs, read_sfrbx_nav(path, p, epochs[0].time)
    _, epochs = read_rtcm3(path, p)
    return epochs, read_rtcm3_nav(path, p)


def _stream(fmt: str, data: bytes, seed: int, max_chunk: int = 3000) -> tuple[list, NavData, Problems]:
    nav, problems = NavData(), Problems(keep=10)
    dec = GnssStreamDecoder(fmt, f"{fmt}+tcp://receiver:1", nav, problems)  # type: ignore[arg-type]
    rnd = random.Random(seed)
    out, i = [], 0
    while i < len(data):
        n = rnd.randint(1, max_chunk)
        out += dec.feed(data[i : i + n])
        i += n
    out += dec.feed(b"", final=True)
    return out, nav, problems


@pytest.mark.parametrize("fmt", FORMATS)
def test_stream_cut_anywhere_equals_the_file(logs: dict[str, Path], fmt: str) -> None:
    epochs, nav = _reference(fmt, logs[fmt])
    data = logs[fmt].read_bytes()
    for seed in range(3):
        got, got_nav, problems = _stream(fmt, data, seed, max_chunk=1 + 2000 * seed)
        assert got == epochs and got_nav.ephemerides == nav.ephemerides and got_nav.iono == nav.iono
        assert problems.total == 0


@pytest.mark.parametrize("msm", [5, 6])
def test_a_base_streaming_msm5_or_msm6_equals_the_file(
    logs: dict[str, Path], tmp_path: Path, msm: int
) -> None:
    """Casters choose the MSM level by bandwidth: an MSM5 (Doppler, coarse) or MSM6 (fine, no
    Doppler) stream decodes as the file reader reads it."""
    sim = logs["rtcm3"].parents[2] / "sim"
    convert_recording(sim, "rtcm3", tmp_path / "m", msm=msm)
    path = tmp_path / "m" / "vehicles" / "u1.rtcm3"
    epochs, nav = _reference("rtcm3", path)
    got, got_nav, problems = _stream("rtcm3", path.read_bytes(), seed=msm)
    assert got == epochs and len(got) == 60 and got_nav.ephemerides == nav.ephemerides
    assert problems.total == 0
    assert any(s.doppler_hz == s.doppler_hz for s in got[0].sats) == (msm == 5)  # NaN: no Doppler


@pytest.mark.parametrize("fmt", FORMATS)
def test_scanner_fed_in_pieces_finds_the_file_scan_frames(logs: dict[str, Path], fmt: str) -> None:
    data = logs[fmt].read_bytes()
    rnd = random.Random(1)
    damaged = bytearray(data)
    for _ in range(200):  # garbage in places, so false syncs and skipped runs occur
        damaged[rnd.randrange(len(damaged))] ^= 1 << rnd.randrange(8)
    damaged = bytes(damaged)
    whole = [f for f in (ubx_frames if fmt == "ubx" else rtcm_frames)(damaged) if isinstance(f, Frame)]
    scanner = (ubx_scanner if fmt == "ubx" else rtcm_scanner)()
    pieces, i, skipped = [], 0, 0
    while i < len(damaged):
        n = rnd.randint(1, 500)
        for item in scanner.feed(damaged[i : i + n]):
            if isinstance(item, Frame):
                pieces.append(item)
            else:
                skipped += item.length
        i += n
    for item in scanner.feed(b"", final=True):
        skipped += item.length if not isinstance(item, Frame) else 0
    assert pieces == whole
    assert skipped + sum(len(f.raw) for f in pieces) == len(damaged)  # every byte accounted for
    assert len(scanner.buf) == 0


def _frames(data: bytes, fmt: str) -> list[bytes]:
    return [f.raw for f in (ubx_frames if fmt == "ubx" else rtcm_frames)(data) if isinstance(f, Frame)]


@pytest.mark.parametrize("fmt", FORMATS)
def test_ten_thousand_bad_frames_cost_only_themselves(logs: dict[str, Path], fmt: str) -> None:
    """Every good frame sent twice: once intact, and (10,000 times in all) once garbled, truncated
    or bit-flipped just before it. The intact ones still make every epoch."""
    frames = _frames(logs[fmt].read_bytes(), fmt)
    epochs, nav = _reference(fmt, logs[fmt])
    rnd = random.Random(7)
    stream = bytearray()
    bad = intact = 0
    while bad < 10_000:
        for raw in frames:
            if bad < 10_000:
                kind = bad % 3
                if kind == 0:  # bit flips (in the header too: false lengths)
                    b = bytearray(raw)
                    for _ in range(rnd.randint(1, 4)):
                        b[rnd.randrange(len(b))] ^= 1 << rnd.randrange(8)
                    if bytes(b) != raw:
                        stream += b
                        bad += 1
                elif kind == 1:  # truncated
                    stream += raw[: rnd.randrange(1, len(raw))]
                    bad += 1
                else:  # garbage with syncs in it
                    stream += bytes(rnd.randrange(256) for _ in range(rnd.randint(1, 40))) + raw[:2]
                    bad += 1
            stream += raw
            intact += 1
        if bad >= 10_000:
            break
    got, got_nav, problems = _stream(fmt, bytes(stream), seed=3)
    # each intact frame is found after whatever came before it: every epoch at least once, in order
    unique = []
    for e in got:
        if not unique or e.time > unique[-1].time:
            unique.append(e)
    assert unique == epochs
    assert got_nav.ephemerides == nav.ephemerides
    # every bad frame counted: it lies between two intact frames, so it is one skipped run; except,
    # for UBX, the few multi-bit flips its 16-bit Fletcher checksum cannot see (measured 8 in
    # 3,334), which decode as frames (RTCM's CRC-24Q catches all of them)
    found = sum(isinstance(f, Frame) for f in (ubx_frames if fmt == "ubx" else rtcm_frames)(bytes(stream)))
    undetected = found - intact
    assert problems.counts["garbled-frame"] + undetected == 10_000
    assert undetected <= (20 if fmt == "ubx" else 0)
    assert problems.counts["non-monotonic-time"] + len(got) >= len(epochs)


def test_file_source_yields_the_file(logs: dict[str, Path]) -> None:
    src = FileSource(logs["ubx"], chunk=1000)
    data = b"".join(src.chunks(threading.Event()))
    assert data == logs["ubx"].read_bytes() and src.status.bytes == len(data)
    missing = FileSource(logs["ubx"].with_name("nope.ubx"))
    assert list(missing.chunks(threading.Event())) == [] and "nope.ubx" in (missing.status.last_error or "")


def test_joining_an_rtcm_stream_mid_epoch_drops_the_partial_epoch(logs: dict[str, Path]) -> None:
    """A socket or caster joined in the middle of an epoch's MSMs: that epoch would lack a system,
    so the first epoch after joining is dropped and counted; the rest are the file's."""
    epochs, nav = _reference("rtcm3", logs["rtcm3"])
    known = NavData()
    known.merge(nav)  # what an agent knows from its receiver: the week (MSM carries none)
    frames = _frames(logs["rtcm3"].read_bytes(), "rtcm3")
    msm = [i for i, f in enumerate(frames) if f[3:5] in (b"\x43\x50", b"\x46\x70")]  # 1077, 1127 headers
    joined = b"".join(frames[msm[1] :])  # from the second MSM: the first epoch's GPS MSM is gone
    problems = Problems()
    dec = GnssStreamDecoder("rtcm3", "rtcm3+tcp://base:1", known, problems, mid_stream=True)
    got = dec.feed(joined, final=True)
    assert problems.counts["partial-first-epoch"] == 1
    assert [e.time for e in got] == [e.time for e in epochs[1:]]


def test_a_stray_ephemeris_does_not_move_an_rtcm_stream_by_weeks(logs: dict[str, Path]) -> None:
    """A stream of MSMs only takes its first week from the ephemerides the agent already holds.
    One of them 30 weeks off (a stray record in a navigation file: KLT's HKSC file has one) used
    to move every epoch by 30 weeks when it was the newest; the median of the satellites' newest
    toes (`NavData.reference_time`) ignores it."""
    epochs, nav = _reference("rtcm3", logs["rtcm3"])
    known = NavData()
    known.merge(nav)
    sat = sorted(known.ephemerides)[0]
    last = known.ephemerides[sat][-1]
    known.add(dataclasses.replace(last, toe=GpsTime(last.toe.week + 30, last.toe.tow)))
    msms = b"".join(
        f for f in _frames(logs["rtcm3"].read_bytes(), "rtcm3") if f[3:5] in (b"\x43\x50", b"\x46\x70")
    )
    problems = Problems()
    got = GnssStreamDecoder("rtcm3", "rtcm3+tcp://base:1", known, problems).feed(msms, final=True)
    assert [e.time for e in got] == [e.time for e in epochs]


def test_one_beidou_ephemeris_of_another_week_does_not_move_an_rtcm_stream(
    logs: dict[str, Path], tmp_path: Path
) -> None:
    """A stream's first week comes from its BeiDou 1042s (13-bit weeks). One well-formed 1042
    30 weeks off, arriving first, used to set it alone and move every epoch by 30 weeks; now the
    week waits for two satellites that agree and is their median, as the file reader's."""
    from coplane.recording.rtcm3_ephemeris import ephemeris_frame

    epochs, nav = _reference("rtcm3", logs["rtcm3"])
    bds = sorted(s for s in nav.ephemerides if s.startswith("C"))
    assert len(bds) >= 2
    first = nav.ephemerides[bds[0]][0]
    off = {"week": first.week + 30, "toe": GpsTime(first.toe.week + 30, first.toe.tow)}
    stray = ephemeris_frame(dataclasses.replace(first, **off))  # type: ignore[arg-type]
    data = stray + logs["rtcm3"].read_bytes()
    problems = Problems()
    dec = GnssStreamDecoder("rtcm3", "rtcm3+tcp://base:1", NavData(), problems)
    got = dec.feed(data, final=True)
    assert [e.time for e in got] == [e.time for e in epochs]
    (tmp_path / "u1.rtcm3").write_bytes(data)  # the file reader takes the median of the log's 1042s
    assert [e.time for e in read_rtcm3(tmp_path / "u1.rtcm3", Problems())[1]] == [e.time for e in epochs]


@pytest.mark.parametrize("fmt", FORMATS)
def test_a_reconnect_in_the_middle_of_a_frame_costs_that_frame(logs: dict[str, Path], fmt: str) -> None:
    """The stream drops in the middle of a frame and a new connection starts at a frame boundary
    (RTCM: in the middle of an epoch's MSMs): the cut frame is counted, not glued to the new bytes;
    for RTCM the cut epoch and the first one after the reconnect are dropped; the rest are the file's."""
    epochs, nav = _reference(fmt, logs[fmt])
    known = NavData()
    known.merge(nav)
    frames = _frames(logs[fmt].read_bytes(), fmt)
    cut = len(frames) // 2
    problems = Problems()
    dec = GnssStreamDecoder(fmt, f"{fmt}+tcp://r:1", known, problems, mid_stream=False)  # type: ignore[arg-type]
    got = dec.feed(b"".join(frames[:cut]) + frames[cut][: len(frames[cut]) // 2])
    dec.rejoin()
    got += dec.feed(b"".join(frames[cut + 2 :]), final=True)
    assert problems.counts["garbled-frame"] == 1
    times = [e.time for e in got]
    assert times == sorted(times) and set(times) <= {e.time for e in epochs}
    missing = len(epochs) - len(got)
    assert missing <= (2 if fmt == "ubx" else 3)
    by_t = {e.time: e for e in epochs}
    assert all(by_t[e.time] == e for e in got)
