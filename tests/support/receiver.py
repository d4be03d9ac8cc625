"""A receiver log served over TCP at the pace it was recorded: what a u-blox behind a
serial-to-TCP bridge looks like to an agent (`ubx+tcp://`), for the live-path tests.

Frames before the first epoch (navigation) go out on connect; each epoch's frames go out at
`start_unix_s + (epoch - t0) / speed`. A client that connects late joins at the current epoch, as
with a real receiver. `drop(seconds)` cuts the clients and refuses connections for that long (a
receiver stream that drops). Several clients may connect (a base several agents read).
"""

from __future__ import annotations

import contextlib
import socket
import threading
import time
from pathlib import Path

from coplane.gtime import GpsTime
from coplane.live.decode import GnssStreamDecoder
from coplane.recording.frames import Frame, rtcm_frames, ubx_frames
from coplane.recording.model import NavData
from coplane.recording.problems import Problems


def epochs_of(path: Path, fmt: str) -> tuple[bytes, list[tuple[GpsTime, bytes]]]:
    """(frames before the first epoch, [(epoch time, its frames)]) of a log."""
    dec = GnssStreamDecoder(fmt, str(path), NavData(), Problems())  # type: ignore[arg-type]
    frames = [
        f for f in (ubx_frames if fmt == "ubx" else rtcm_frames)(path.read_bytes()) if isinstance(f, Frame)
    ]
    head, out, cur = b"", [], b""
    for f in frames:
        cur += f.raw
        eps = dec.feed(f.raw)
        if eps:
            out.append((eps[-1].time, cur))
            cur = b""
        elif not out:
            head, cur = head + cur, b""
    return head, out


class PacedReceiver:
    def __init__(self, path: Path, fmt: str, start_unix_s: float, t0: GpsTime, speed: float = 1.0) -> None:
        self.head, self.epochs = epochs_of(path, fmt)
        self.start, self.t0, self.speed = start_unix_s, t0, speed
        self.sock = socket.socket()
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(8)
        self.sock.settimeout(0.2)
        self.port = int(self.sock.getsockname()[1])
        self.stop = threading.Event()
        self.down_until = 0.0
        self.connections = 0
        self.sent_epochs = 0
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def due(self, t: GpsTime) -> float:
        return self.start + (t - self.t0) / self.speed

    def drop(self, seconds: float) -> None:
        """Cut the stream now and refuse connections for `seconds`."""
        self.down_until = time.time() + seconds

    def close(self) -> None:
        self.stop.set()
        self.thread.join(5.0)
        self.sock.close()

    def _serve(self) -> None:
        while not self.stop.is_set():
            try:
                conn, _ = self.sock.accept()
            except TimeoutError:
                continue
            if time.time() < self.down_until:
                conn.close()  # the receiver is away
                continue
            self.connections += 1
            threading.Thread(target=self._client, args=(conn,), daemon=True).start()

    def _client(self, conn: socket.socket) -> None:
        with contextlib.closing(conn):
            self._stream(conn)

    def _stream(self, conn: socket.socket) -> None:
        try:
            conn.sendall(self.head)
            for t, data in self.epochs:
                due = self.due(t)
                if due < time.time() - 0.5 / self.speed:
                    continue  # already past: a receiver has no history to give
                while time.time() < due:
                    if self.stop.is_set() or time.time() < self.down_until:
                        return
                    time.sleep(min(0.02, max(0.0, due - time.time())))
                if time.time() < self.down_until:
                    return
                conn.sendall(data)
                self.sent_epochs += 1
            while not self.stop.is_set():  # the log is over; a receiver would go on, this one idles
                time.sleep(0.1)
        except OSError:
            return
