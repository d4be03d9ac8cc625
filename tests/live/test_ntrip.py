"""The NTRIP client (coplane's own, `live/ntrip.py`) against a real caster (pygnssutils' socket
server in NTRIP mode, its own process, `support/ntrip_caster.py`): the log's frames arrive; a wrong
password or mountpoint is a clear status, never an exception, never the password; a caster restart
is a reconnect after a backoff; stop ends the reader at once; the answer forms of NTRIP 1 and 2
(chunked) and the GGA upload against a scripted caster."""

from __future__ import annotations

import logging
import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from support.ntrip_caster import MOUNTPOINT, start_caster
from support.receiver import epochs_of

from coplane.fleet.launcher import free_port
from coplane.live.ntrip import NtripSource
from coplane.live.status import Backoff
from coplane.recording.convert import convert_recording
from coplane.recording.frames import Frame, rtcm_frames
from coplane.recording.reader import open_recording
from coplane.sim.generate import simulate

SECRET = "pw-s3cret"
GGA = "$GPGGA,123519.00,4807.03800,N,01131.00000,E,1,08,0.9,545.4,M,46.9,M,,*69"


class CountingBackoff(Backoff):
    """A Backoff that counts its waits (the reconnect must have used it)."""

    waits = 0

    def wait(self, stop: threading.Event) -> bool:
        self.waits += 1
        return super().wait(stop)


@pytest.fixture(scope="module")
def caster(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[int, Path, float]]:
    root = tmp_path_factory.mktemp("ntrip")
    simulate("urban-loop", root / "sim", 2, 40, seed=3)
    convert_recording(root / "sim", "rtcm3", root / "rtcm3")
    base = open_recording(root / "rtcm3").manifest.base
    assert base is not None
    _, epochs = epochs_of(base.obs, "rtcm3")
    port = free_port()
    start = time.time() + 1.0
    p = start_caster(base.obs, port, "me", SECRET, start, epochs[0][0])
    yield port, base.obs, start
    p.kill()
    p.wait()


def _read(src: NtripSource, seconds: float) -> tuple[list[bytes], threading.Event, threading.Thread]:
    stop = threading.Event()
    got: list[bytes] = []
    th = threading.Thread(target=lambda: got.extend(src.chunks(stop)), daemon=True)
    th.start()
    time.sleep(seconds)
    return got, stop, th


def test_frames_arrive_as_sent(caster: tuple[int, Path, float]) -> None:
    port, log, _ = caster
    src = NtripSource("127.0.0.1", port, MOUNTPOINT, "me", SECRET, backoff=Backoff(0.2, 1.0))
    got, stop, th = _read(src, 4.0)
    stop.set()
    th.join(2.0)
    frames = [f.raw for f in rtcm_frames(b"".join(got)) if isinstance(f, Frame)]
    sent = [f.raw for f in rtcm_frames(log.read_bytes()) if isinstance(f, Frame)]
    assert len(frames) >= 4  # about two MSM per second
    i = sent.index(frames[0])
    assert frames == sent[i : i + len(frames)]  # in order, none lost or changed
    assert src.status.connects == 1 and src.status.bytes == sum(map(len, got))


@pytest.mark.parametrize(
    ("mount", "password", "why"),
    [(MOUNTPOINT, "wrong-pw", "401 Unauthorized"), ("NOPE", SECRET, "no mountpoint 'NOPE'")],
)
def test_wrong_credentials_or_mountpoint(
    caster: tuple[int, Path, float], mount: str, password: str, why: str, caplog: pytest.LogCaptureFixture
) -> None:
    port, _, _ = caster
    caplog.set_level(logging.DEBUG)
    src = NtripSource("127.0.0.1", port, mount, "me", password, backoff=Backoff(0.2, 0.5))
    got, stop, th = _read(src, 2.0)
    stop.set()
    th.join(2.0)
    assert not th.is_alive() and got == [] and not src.status.connected
    assert why in (src.status.last_error or "") and src.status.failures >= 2  # it keeps trying
    assert password not in caplog.text and password not in str(src.status.snapshot())
    assert "me:" not in caplog.text and "Basic" not in caplog.text  # nor user:password in base64


def test_caster_restart_is_a_reconnect(tmp_path: Path, caster: tuple[int, Path, float]) -> None:
    _, log, start = caster
    _, epochs = epochs_of(log, "rtcm3")
    port = free_port()
    p = start_caster(log, port, "me", SECRET, start, epochs[0][0])
    backoff = CountingBackoff(0.2, 1.0)
    src = NtripSource("127.0.0.1", port, MOUNTPOINT, "me", SECRET, backoff=backoff)
    got, stop, th = _read(src, 3.0)
    assert src.status.connected and got and backoff.waits == 0
    p.kill()
    p.wait()
    deadline = time.monotonic() + 10
    while src.status.connected and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not src.status.connected and "closed" in (src.status.last_error or "")
    n = len(got)
    p = start_caster(log, port, "me", SECRET, start, epochs[0][0])
    deadline = time.monotonic() + 15
    while len(got) <= n + 2 and time.monotonic() < deadline:
        time.sleep(0.05)
    try:
        assert src.status.connected and src.status.connects == 2 and len(got) > n
        assert backoff.waits >= 1 and src.status.failures == backoff.waits  # refused while down
        frames = [f for f in rtcm_frames(b"".join(got[n:])) if isinstance(f, Frame)]
        assert frames  # whole, CRC-good frames after the reconnect
        t0 = time.monotonic()
        stop.set()
        th.join(3.0)
        assert not th.is_alive() and time.monotonic() - t0 < 2.0
    finally:
        p.kill()
        p.wait()


@pytest.mark.parametrize(
    ("answer", "body"),
    [
        (b"HTTP/1.1 200 OK\r\nTransfer-Encoding: chunked\r\n\r\n", "chunked"),
        (b"ICY 200 OK\r\n", "raw"),
        (b"HTTP/1.1 200 OK\r\nContent-Type: gnss/data\r\n\r\n", "raw"),
    ],
)
def test_answer_forms(answer: bytes, body: str) -> None:
    """NTRIP 2 chunked transfer, NTRIP 1 `ICY 200 OK`, plain HTTP: the same bytes come out, and
    the first bytes after the header are not lost (pygnssutils' client loses them)."""
    payload = bytes(range(256)) * 40
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(1)
    port = server.getsockname()[1]

    def serve() -> None:
        conn, _ = server.accept()
        req = conn.recv(4096)
        assert b"Authorization: Basic " in req
        if body == "chunked":
            data = answer
            for i in range(0, len(payload), 1000):
                part = payload[i : i + 1000]
                data += f"{len(part):x}\r\n".encode() + part + b"\r\n"
            conn.sendall(data + b"0\r\n\r\n")
        else:
            conn.sendall(answer + payload)  # header and data in one segment
        time.sleep(0.5)
        conn.close()

    threading.Thread(target=serve, daemon=True).start()
    src = NtripSource(
        "127.0.0.1", port, "M", "me", SECRET, backoff=Backoff(5.0, 5.0), version=1 if b"ICY" in answer else 2
    )
    stop = threading.Event()
    got = b""
    for data in src.chunks(stop):
        got += data
        if len(got) >= len(payload):
            stop.set()
    server.close()
    assert got == payload


def test_gga_upload() -> None:
    """A VRS-like caster that sends nothing until the rover's GGA: the sentence goes out after the
    answer, again every interval, and a gga() without a position yet (None) is asked again."""
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(1)
    port = server.getsockname()[1]
    received: list[bytes] = []

    def serve() -> None:
        conn, _ = server.accept()
        conn.settimeout(5.0)
        conn.recv(4096)  # the request
        conn.sendall(b"ICY 200 OK\r\n")
        buf = b""
        while buf.count(b"\r\n") < 3:
            more = conn.recv(4096)
            if not more:
                break
            buf += more
            if b"\r\n" in buf and not received:
                conn.sendall(b"\xd3\x00\x00\x47\xea\x4b")  # data only after the first GGA
            received[:] = buf.split(b"\r\n")[:-1]
        conn.close()

    threading.Thread(target=serve, daemon=True).start()
    answers = iter([None])
    calls = 0

    def gga() -> str | None:
        nonlocal calls
        calls += 1
        return next(answers, GGA)

    src = NtripSource(
        "127.0.0.1", port, "VRS", backoff=Backoff(5.0, 5.0), version=1, gga=gga, gga_interval_s=0.2
    )
    got, stop, th = _read(src, 0.0)
    deadline = time.monotonic() + 5.0
    while len(received) < 3 and time.monotonic() < deadline:
        time.sleep(0.05)
    stop.set()
    th.join(2.0)
    server.close()
    assert not th.is_alive() and got == [b"\xd3\x00\x00\x47\xea\x4b"]
    assert received[:3] == [GGA.encode()] * 3 and calls >= 4  # None first, then every 0.2 s
