"""Byte transports of a live receiver: a file, a TCP socket, a serial port (pyserial).

Each yields the bytes as they arrive and owns its reconnects: a dropped TCP stream or an unplugged
receiver is logged once per outage, retried with exponential backoff, and shows in `status`
(connected, reconnects, age of the last byte). Nothing here parses: framing and decoding are
`live/decode.py`'s job, so a reconnect in the middle of a frame costs that frame only.
"""

from __future__ import annotations

import logging
import socket
import threading
from collections.abc import Iterator
from pathlib import Path

from coplane.live.status import Backoff, SourceStatus

log = logging.getLogger("coplane.live")
CHUNK = 65536


def end_of_connection(status: SourceStatus, backoff: Backoff, stop: threading.Event, why: str) -> bool:
    """After a connection ended: True when the reader should return (`stop` set, also during the
    backoff), else the outage is recorded and the backoff waited, and it should reconnect."""
    if stop.is_set():
        status.connected = False
        return True
    report_down(status, why)
    return backoff.wait(stop)


def report_down(status: SourceStatus, reason: str) -> None:
    """Record a failed connect or a lost connection; log once per outage (a receiver that stays
    away must not flood the log)."""
    first = status.connected or status.last_error is None
    status.down(reason)
    if first:
        log.warning("live source down, retrying", extra={"source": status.name, "error": reason})


class FileSource:
    """A receiver log read once, in chunks (a replay through the live path, or a FIFO)."""

    def __init__(self, path: str | Path, name: str | None = None, chunk: int = CHUNK) -> None:
        self.path = Path(path)
        self.chunk = chunk
        self.status = SourceStatus(name or f"file://{self.path}")

    def chunks(self, stop: threading.Event) -> Iterator[bytes]:
        """The file's bytes; ends at its end (a read error is recorded, not raised)."""
        try:
            with self.path.open("rb") as f:
                self.status.up()
                while not stop.is_set():
                    data = f.read(self.chunk)
                    if not data:
                        break
                    self.status.data(len(data))
                    yield data
        except OSError as exc:
            self.status.down(f"{self.path}: {exc.strerror or exc}")
            log.error(
                "live source failed", extra={"source": self.status.name, "error": self.status.last_error}
            )
            return
        self.status.connected = False


class TcpSource:
    """A receiver (or a serial-to-TCP bridge) serving its stream on a TCP port; we connect to it.

    A connection that is refused, reset or silent for `timeout_s` is closed and retried with
    backoff, for as long as the agent runs.
    """

    def __init__(
        self,
        host: str,
        port: int,
        name: str | None = None,
        timeout_s: float = 5.0,
        backoff: Backoff | None = None,
    ) -> None:
        self.host, self.port, self.timeout_s = host, port, timeout_s
        self.backoff = backoff or Backoff()
        self.status = SourceStatus(name or f"tcp://{host}:{port}")

    def chunks(self, stop: threading.Event) -> Iterator[bytes]:
        """The stream's bytes across reconnects, until `stop`."""
        while not stop.is_set():
            try:
                sock = socket.create_connection((self.host, self.port), timeout=self.timeout_s)
            except OSError as exc:
                report_down(self.status, f"cannot connect to {self.host}:{self.port}: {exc.strerror or exc}")
                if self.backoff.wait(stop):
                    return
                continue
            self.status.up()
            log.info("live source connected", extra={"source": self.status.name})
            why = "closed by the peer"
            try:
                sock.settimeout(min(0.5, self.timeout_s))
                silent = 0.0
                while not stop.is_set():
                    try:
                        data = sock.recv(CHUNK)
                    except TimeoutError:
                        silent += min(0.5, self.timeout_s)
                        if silent >= self.timeout_s:
                            why = f"no data for {self.timeout_s:g} s"
                            break
                        continue
                    if not data:
                        break
                    silent = 0.0
                    self.backoff.reset()
                    self.status.data(len(data))
                    yield data
            except OSError as exc:
                why = f"connection lost: {exc.strerror or exc}"
            finally:
                sock.close()
            if end_of_connection(self.status, self.backoff, stop, f"{self.host}:{self.port}: {why}"):
                return


class SerialSource:
    """A receiver on a serial port (USB CDC-ACM or UART), through pyserial; re-opened with backoff
    when it disappears (an unplugged or power-cycled receiver)."""

    def __init__(
        self, device: str, baud: int, name: str | None = None, backoff: Backoff | None = None
    ) -> None:
        self.device, self.baud = device, baud
        self.backoff = backoff or Backoff()
        self.status = SourceStatus(name or f"serial://{device}?baud={baud}")

    def chunks(self, stop: threading.Event) -> Iterator[bytes]:
        """The port's bytes across re-opens, until `stop`."""
        import serial  # pyserial: only agents with a serial receiver need it loaded

        while not stop.is_set():
            try:
                port = serial.Serial(self.device, self.baud, timeout=0.5)
            except (serial.SerialException, OSError, ValueError) as exc:
                report_down(self.status, f"cannot open {self.device}: {exc}")
                if self.backoff.wait(stop):
                    return
                continue
            self.status.up()
            why = "port closed"
            try:
                while not stop.is_set():
                    data = port.read(max(1, min(CHUNK, port.in_waiting or 1)))
                    if data:
                        self.backoff.reset()
                        self.status.data(len(data))
                        yield data
            except (serial.SerialException, OSError) as exc:
                why = f"{self.device}: {exc}"
            finally:
                port.close()
            if end_of_connection(self.status, self.backoff, stop, why):
                return
