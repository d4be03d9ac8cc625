"""Base corrections from an NTRIP caster: an NTRIP 1/2 client on a plain socket.

Why not pygnssutils' `GNSSNTRIPClient` (tried first, pygnssutils 1.3.1): it discards the first
chunk of data that follows the caster's response header (measured: the base's first epoch after
every connect is lost, so a live run's first DGNSS epoch differs from the replay's), spins on
empty reads once a caster closes the connection, decodes no chunked transfer encoding (NTRIP 2
casters may use it) and gives up after a fixed number of retries. The protocol itself is one HTTP
GET, so it is done here; the caster in the tests is pygnssutils' own server in NTRIP mode.
It also answers a 401 or a sourcetable by stopping for good (a caster that is being reconfigured
would end the agent's corrections) and takes the GGA it uploads from a GUI application object's
`get_coordinates()`, where an agent has a plain callable.

What an agent gets:
* the raw stream as a `ByteSource`: frames go through the same frame search and decoder as any
  other stream (`live/decode.py`), so bytes split anywhere cost nothing;
* reconnects that never end, with backoff: a refused connection, an error answer, a caster that
  closes or goes silent for `timeout_s`;
* a status naming host:port/mount and the caster's answer (`401 Unauthorized`, `sourcetable: no
  mountpoint 'X'`, `no data for 10 s`), never the credentials; the age of the last byte;
* optionally the rover's position uploaded as an NMEA GGA sentence (`gga`), right after the caster
  accepted the request and every `gga_interval_s` (10 s) after: VRS and nearest-base casters
  choose or compute the stream from it, and some send nothing until the first GGA arrives.
"""

from __future__ import annotations

import base64
import logging
import socket
import threading
import time
from collections.abc import Callable, Iterator

from coplane.live.sources import CHUNK, end_of_connection
from coplane.live.status import Backoff, SourceStatus

log = logging.getLogger("coplane.live")
MAX_HEADER = 16384  # bytes of response header before the caster is taken for something else
USER_AGENT = "NTRIP coplane"
GGA_INTERVAL_S = 10.0  # NTRIP practice: a VRS caster follows the rover with this
GGA_RETRY_S = 1.0  # no position yet (gga() gave None): asked again this soon


class NtripError(Exception):
    """The caster answered, but not with a stream (the reason is shown, and retried)."""


class NtripSource:
    """RTCM 3 bytes from `host:port/mountpoint` until `stop`, across caster restarts."""

    def __init__(
        self,
        host: str,
        port: int,
        mountpoint: str,
        user: str | None = None,
        password: str | None = None,
        *,
        name: str | None = None,
        backoff: Backoff | None = None,
        timeout_s: float = 10.0,
        version: int = 2,
        gga: Callable[[], str | None] | None = None,
        gga_interval_s: float = GGA_INTERVAL_S,
    ) -> None:
        """`gga`: the rover's position as an NMEA GGA sentence (None while it has none), sent
        to the caster after each connect and every `gga_interval_s`; omit for a fixed base."""
        self.host, self.port, self.mountpoint = host, port, mountpoint
        self._auth = base64.b64encode(f"{user}:{password or ''}".encode()).decode() if user else None
        self.timeout_s = timeout_s
        self.version = version
        self.gga, self.gga_interval_s = gga, gga_interval_s
        self.backoff = backoff or Backoff()
        self.where = f"{host}:{port}/{mountpoint}"
        self.status = SourceStatus(name or f"ntrip://{self.where}")

    def request(self) -> bytes:
        """The GET of NTRIP 2 (HTTP/1.1 + Ntrip-Version) or NTRIP 1 (HTTP/1.0)."""
        lines = [
            f"GET /{self.mountpoint} HTTP/{'1.1' if self.version == 2 else '1.0'}",
            f"Host: {self.host}:{self.port}",
            f"User-Agent: {USER_AGENT}",
            "Accept: */*",
            "Connection: close",
        ]
        if self.version == 2:
            lines.append("Ntrip-Version: Ntrip/2.0")
        if self._auth:
            lines.append(f"Authorization: Basic {self._auth}")
        return ("\r\n".join(lines) + "\r\n\r\n").encode()

    def _header(self, sock: socket.socket) -> tuple[bytes, bool]:
        """Read the response header; (bytes after it, chunked?) or NtripError."""
        buf = b""
        while True:
            if buf.startswith(b"ICY 200 OK\r\n"):  # NTRIP 1: the status line alone, then data
                return buf[len(b"ICY 200 OK\r\n") :], False
            end = buf.find(b"\r\n\r\n")
            if end >= 0:
                break
            if len(buf) > MAX_HEADER:
                raise NtripError(f"{self.where}: no HTTP answer in {MAX_HEADER} bytes")
            data = sock.recv(CHUNK)
            if not data:
                raise NtripError(f"{self.where}: closed by the caster before answering")
            buf += data
        head = buf[:end].decode("latin-1", errors="replace").split("\r\n")
        rest = buf[end + 4 :]
        status = head[0].split(" ", 2)
        fields = {k.strip().lower(): v.strip() for k, _, v in (h.partition(":") for h in head[1:])}
        if status[0] == "SOURCETABLE" or "sourcetable" in fields.get("content-type", ""):
            raise NtripError(f"{self.where}: caster sent its sourcetable: no mountpoint {self.mountpoint!r}")
        if len(status) < 2 or status[1] != "200":
            raise NtripError(f"{self.where}: caster answered {' '.join(status[1:]) or head[0][:80]}")
        return rest, "chunked" in fields.get("transfer-encoding", "").lower()

    def chunks(self, stop: threading.Event) -> Iterator[bytes]:
        """The caster's RTCM 3 stream as it arrives; never raises on network errors."""
        while not stop.is_set():
            why = ""
            try:
                with socket.create_connection((self.host, self.port), timeout=self.timeout_s) as sock:
                    sock.sendall(self.request())
                    first, chunked = self._header(sock)
                    self.status.up()
                    log.info("ntrip corrections flowing", extra={"source": self.status.name})
                    sock.settimeout(min(0.5, self.timeout_s))
                    tick = _GgaUpload(sock, self.gga, self.gga_interval_s) if self.gga else None
                    if tick:
                        tick()  # before reading: a VRS caster may wait for it
                    body = _dechunk(first, sock, stop, self.timeout_s, tick) if chunked else None
                    for data in body or _raw(first, sock, stop, self.timeout_s, tick):
                        self.backoff.reset()
                        self.status.data(len(data))
                        yield data
                    why = f"{self.where}: connection closed by the caster"
            except NtripError as exc:
                why = str(exc)
            except TimeoutError:
                why = f"{self.where}: no data for {self.timeout_s:g} s"
            except OSError as exc:
                why = f"{self.where}: {exc.strerror or exc}"
            if end_of_connection(self.status, self.backoff, stop, why):
                return


class _GgaUpload:
    """The rover's GGA sentence sent on one connection: when called, if it is due."""

    def __init__(self, sock: socket.socket, gga: Callable[[], str | None], interval_s: float) -> None:
        self.sock, self.gga, self.interval_s = sock, gga, interval_s
        self.due = 0.0

    def __call__(self) -> None:
        now = time.monotonic()
        if now < self.due:
            return
        try:
            sentence = self.gga()
        except Exception as exc:  # the caller's position source: its bug must not end the stream
            log.warning("ntrip: gga() failed, nothing sent", extra={"error": repr(exc)})
            sentence = None
        if not sentence:
            self.due = now + GGA_RETRY_S
            return
        self.due = now + self.interval_s
        self.sock.sendall(sentence.strip().encode("ascii", errors="replace") + b"\r\n")  # OSError: reconnect


def _raw(
    first: bytes,
    sock: socket.socket,
    stop: threading.Event,
    timeout_s: float,
    tick: Callable[[], None] | None = None,
) -> Iterator[bytes]:
    """The stream as is (TimeoutError after `timeout_s` without a byte); `tick` runs between
    reads (at least every half second: the GGA upload)."""
    if first:
        yield first
    silent = 0.0
    while not stop.is_set():
        if tick:
            tick()
        try:
            data = sock.recv(CHUNK)
        except TimeoutError:
            silent += sock.gettimeout() or 0.5
            if silent >= timeout_s:
                raise
            continue
        if not data:
            return
        silent = 0.0
        yield data


def _dechunk(
    first: bytes,
    sock: socket.socket,
    stop: threading.Event,
    timeout_s: float,
    tick: Callable[[], None] | None = None,
) -> Iterator[bytes]:
    """HTTP chunked transfer decoding (`size CRLF data CRLF`), as some NTRIP 2 casters send."""
    buf = first
    raw = _raw(b"", sock, stop, timeout_s, tick)
    while True:
        line_end = buf.find(b"\r\n")
        if line_end < 0:
            more = next(raw, None)
            if more is None:
                return
            buf += more
            continue
        size_text = buf[:line_end].split(b";")[0].strip()
        try:
            size = int(size_text, 16)
        except ValueError:
            raise NtripError(f"bad chunk size {size_text[:20]!r}") from None
        if size == 0:
            return
        while len(buf) < line_end + 2 + size + 2:
            more = next(raw, None)
            if more is None:
                return
            buf += more
        yield buf[line_end + 2 : line_end + 2 + size]
        buf = buf[line_end + 2 + size + 2 :]
