"""Source URLs (every form, every error names its part and never the password) and the UWB line
protocol (bad lines counted and skipped, the replay's ranges per epoch, UDP end to end)."""

from __future__ import annotations

import socket
import threading
import time
from pathlib import Path

import pytest

from coplane.errors import ConfigError
from coplane.gtime import GpsTime
from coplane.live.urls import parse_source
from coplane.live.uwb import MAX_BUFFERED, UwbInput, UwbUdpSource
from coplane.recording.problems import Problems
from coplane.recording.reader import open_recording
from coplane.replay import uwb_for_vehicle, vehicle_schedule
from coplane.sim.generate import simulate


def test_url_forms(tmp_path: Path) -> None:
    log = tmp_path / "log.ubx"
    log.write_bytes(b"")
    u = parse_source("ubx+tcp://10.0.0.5:5000", option="--gnss", role="gnss")
    assert (u.transport, u.format, u.host, u.port) == ("tcp", "ubx", "10.0.0.5", 5000)
    u = parse_source("rtcm3+serial:///dev/ttyACM0?baud=460800", option="--gnss", role="gnss")
    assert (u.transport, u.format, u.path, u.baud) == ("serial", "rtcm3", "/dev/ttyACM0", 460800)
    assert parse_source("ubx+serial:///dev/ttyACM0", option="--gnss", role="gnss").baud == 115200
    u = parse_source(f"file://{log}", option="--gnss", role="gnss")
    assert (u.transport, u.format, u.path) == ("file", "ubx", str(log))
    u = parse_source("ntrip://me:s3cret@caster.example:2102/MOUNT1", option="--base", role="base")
    assert (u.transport, u.format, u.host, u.port, u.mountpoint) == (
        "ntrip",
        "rtcm3",
        "caster.example",
        2102,
        "MOUNT1",
    )
    assert (u.user, u.password) == ("me", "s3cret")
    assert "s3cret" not in str(u) and "s3cret" not in repr(u) and "me:***@" in u.redacted()
    assert parse_source("ntrip://caster.example/M", option="--base", role="base").port == 2101
    assert parse_source("ntrip://caster.example/M?version=1", option="--base", role="base").version == 1
    u = parse_source("udp://:5600", option="--uwb", role="uwb")
    assert (u.transport, u.format, u.host, u.port) == ("udp", "uwb", None, 5600)


@pytest.mark.parametrize(
    ("url", "role", "part"),
    [
        ("ubx+tcp://host", "gnss", "missing port"),
        ("ubx+tcp://host:99999", "gnss", "port"),
        ("ubx+tcp://host:abc", "gnss", "port"),
        ("ubx+tcp://:5000", "gnss", "missing host"),
        ("gps+tcp://host:1", "gnss", "unknown format 'gps'"),
        ("ubx+ftp://host:1", "gnss", "unknown transport 'ftp'"),
        ("ubx+udp://host:1", "gnss", "transport 'udp' is not for gnss"),
        ("ubx+tcp://host:1", "base", "format 'ubx' is not for base"),
        ("tcp://host:1", "gnss", "format missing"),
        ("ntrip://u:pw-secret@host:2101/", "base", "mountpoint"),
        ("ntrip://u:pw-secret@host:2101/M?version=3", "base", "version '3'"),
        ("ubx+serial:///dev/ttyACM0?baud=fast", "gnss", "baud 'fast'"),
        ("ubx+serial:///dev/ttyACM0?speed=9600", "gnss", "unknown query parameter 'speed'"),
        ("ubx+file:///no/such/file.ubx", "gnss", "not found"),
        ("ubx+tcp://u:pw-secret@host:1", "gnss", "credentials are only for ntrip"),
        ("localhost:5000", "gnss", "no scheme"),
        ("udp://:0", "uwb", "outside 1..65535"),
    ],
)
def test_url_errors_name_the_part(url: str, role: str, part: str) -> None:
    with pytest.raises(ConfigError) as e:
        parse_source(url, option="--x", role=role)  # type: ignore[arg-type]
    msg = str(e.value)
    assert part in msg and msg.startswith("--x ") and "pw-secret" not in msg


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return simulate("urban-loop", tmp_path_factory.mktemp("uwb") / "rec", 3, 30, seed=3)


def test_lines_give_the_replays_ranges(recording: Path) -> None:
    rec = open_recording(recording)
    man = rec.manifest
    assert man.uwb is not None
    text = man.uwb.file.read_bytes()
    ids = [v.id for v in man.vehicles]
    for vid in ids:
        schedule = vehicle_schedule(rec.vehicle_epochs(vid), man.interval_s)
        ref = uwb_for_vehicle(rec.uwb(), vid, (t for t, _ in schedule), man.interval_s)
        inp = UwbInput(vid, ids, Problems())
        for i in range(0, len(text), 97):  # lines cut between chunks
            inp.feed_text(text[i : i + 97], "file://uwb.csv")
        inp.feed_text(b"", "file://uwb.csv", final=True)
        got = {t: inp.take(t, man.interval_s) for t, _ in schedule}
        assert {t: r for t, r in got.items() if r} == ref
        assert inp.counts["other-vehicles"] + inp.counts["to-me"] > 0  # others' rows seen and left out


def test_bad_lines_are_counted_and_cost_only_themselves() -> None:
    p = Problems()
    inp = UwbInput("u1", ["u1", "u2"], p, max_range_m=500.0)
    good = "2100,100.0,u1,u2,12.5"
    bad = [
        "2100,100.0,u1,u2",  # fields
        "2100,abc,u1,u2,12.5",  # time
        "2100,100.0,u1,u9,12.5",  # unknown vehicle
        "2100,100.0,u1,u1,12.5",  # itself
        "2100,100.0,u1,u2,-1",  # range
        "2100,100.0,u1,u2,nan",  # NaN
        "2100,100.0,u1,u2,9000",  # beyond max_range_m
        "\x00\xff garbage",
        "x" * 300,
    ]
    inp.feed_datagram(
        "\n".join([*bad, good, "# comment", "gps_week,tow_s,from_id,to_id,range_m"]).encode(), "udp://:1"
    )
    assert p.total == len(bad) and inp.counts["kept"] == 1
    assert all("udp://:1" in str(item) for item in p.items)
    assert [r.range_m for r in inp.take(GpsTime(2100, 100.0), 1.0)] == [12.5]


def test_memory_is_bounded() -> None:
    inp = UwbInput("u1", ["u1", "u2"], Problems())
    lines = "\n".join(f"2100,{100 + i * 0.001:.3f},u1,u2,10.0" for i in range(MAX_BUFFERED + 500))
    inp.feed_datagram(lines.encode(), "udp")
    assert len(inp.pending) == MAX_BUFFERED and inp.counts["dropped-buffer-full"] == 500


def test_udp_end_to_end() -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    src = UwbUdpSource("127.0.0.1", port)
    stop = threading.Event()
    got: list[bytes] = []
    th = threading.Thread(target=lambda: got.extend(src.chunks(stop)), daemon=True)
    th.start()
    deadline = time.monotonic() + 5
    while not src.status.connected and time.monotonic() < deadline:
        time.sleep(0.01)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
        tx.sendto(b"2100,100.0,u1,u2,12.5\nnot a line\n2100,100.0,u1,u3,20.0\n", ("127.0.0.1", port))
    while not got and time.monotonic() < deadline:
        time.sleep(0.01)
    stop.set()
    th.join(2.0)
    p = Problems()
    inp = UwbInput("u1", ["u1", "u2", "u3"], p)
    for d in got:
        inp.feed_datagram(d, src.status.name)
    assert len(inp.take(GpsTime(2100, 100.0), 1.0)) == 2 and p.total == 1
