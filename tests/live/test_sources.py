"""Byte transports: a TCP receiver that drops and comes back, a serial port (a pseudo-terminal),
stop ending a reader promptly, and the status users see (connected, reconnects, age, error)."""

from __future__ import annotations

import os
import socket
import threading
import time
import tty
from collections.abc import Iterator

from coplane.live.sources import SerialSource, TcpSource
from coplane.live.status import Backoff


def _collect(chunks: Iterator[bytes], out: list[bytes]) -> threading.Thread:
    th = threading.Thread(target=lambda: out.extend(chunks), daemon=True)
    th.start()
    return th


def _wait(cond, timeout: float = 10.0) -> None:  # type: ignore[no-untyped-def]
    deadline = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.02)


def test_tcp_source_reconnects_after_the_receiver_drops() -> None:
    server = socket.socket()
    server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    server.bind(("127.0.0.1", 0))
    server.listen(1)
    port = server.getsockname()[1]
    src = TcpSource("127.0.0.1", port, backoff=Backoff(0.05, 0.2))
    stop = threading.Event()
    got: list[bytes] = []
    th = _collect(src.chunks(stop), got)
    conn, _ = server.accept()
    conn.sendall(b"first")
    _wait(lambda: b"".join(got) == b"first")
    assert src.status.connected and src.status.connects == 1
    conn.close()  # the receiver drops
    _wait(lambda: not src.status.connected)
    assert "closed by the peer" in (src.status.last_error or "")
    conn, _ = server.accept()  # and comes back: the source reconnects by itself
    conn.sendall(b"second")
    _wait(lambda: b"".join(got) == b"firstsecond")
    assert src.status.connects == 2 and src.status.failures >= 1 and src.status.age_s() is not None
    t0 = time.monotonic()
    stop.set()
    th.join(3.0)
    assert not th.is_alive() and time.monotonic() - t0 < 2.0
    conn.close()
    server.close()


def test_tcp_source_retries_a_receiver_that_is_not_there_yet() -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]  # nobody listens here
    src = TcpSource("127.0.0.1", port, backoff=Backoff(0.05, 0.1))
    stop = threading.Event()
    got: list[bytes] = []
    th = _collect(src.chunks(stop), got)
    _wait(lambda: src.status.failures >= 3)
    assert not src.status.connected and f"127.0.0.1:{port}" in (src.status.last_error or "")
    stop.set()
    th.join(3.0)
    assert not th.is_alive() and got == []


def test_tcp_source_closes_a_silent_connection() -> None:
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(2)
    port = server.getsockname()[1]
    src = TcpSource("127.0.0.1", port, timeout_s=0.5, backoff=Backoff(0.05, 0.1))
    stop = threading.Event()
    th = _collect(src.chunks(stop), [])
    a, _ = server.accept()  # connected, but the receiver sends nothing
    _wait(lambda: "no data for 0.5 s" in (src.status.last_error or ""))
    b, _ = server.accept()  # and it tried again
    stop.set()
    th.join(3.0)
    for c in (a, b, server):
        c.close()


def test_serial_source_reads_a_port() -> None:
    master, slave = os.openpty()
    tty.setraw(slave)
    src = SerialSource(os.ttyname(slave), 115200, backoff=Backoff(0.05, 0.1))
    stop = threading.Event()
    got: list[bytes] = []
    th = _collect(src.chunks(stop), got)
    _wait(lambda: src.status.connected)
    os.write(master, b"\xb5\x62hello")
    _wait(lambda: b"".join(got) == b"\xb5\x62hello")
    stop.set()
    th.join(3.0)
    assert not th.is_alive()
    os.close(master)
    os.close(slave)


def test_serial_source_retries_a_missing_device() -> None:
    src = SerialSource("/dev/coplane-no-such-tty", 9600, backoff=Backoff(0.05, 0.1))
    stop = threading.Event()
    th = _collect(src.chunks(stop), [])
    _wait(lambda: src.status.failures >= 2)
    assert "/dev/coplane-no-such-tty" in (src.status.last_error or "")
    stop.set()
    th.join(3.0)
    assert not th.is_alive()
