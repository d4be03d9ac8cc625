"""UWB ranges live: the uwb.csv columns as a line protocol over UDP, serial or a file.

    gps_week,tow_s,from_id,to_id,range_m        e.g.  2100,345600.0,u1,u2,12.3456

One range per line, UTF-8, `\\n` or `\\r\\n`; a datagram may hold several lines; lines starting with
`#` and a header line (`gps_week,...`) are skipped. A line is checked exactly as a uwb.csv row is
(`recording.csvfiles.uwb_range`): a bad one is counted in `problems`, named by source and line,
and costs only itself.

A vehicle keeps the ranges it measured (`from_id` is itself) to known peers, the replay's rule
(`replay.uwb_for_vehicle`): a radio that also reports its peers' ranges, or other vehicles', is
counted by reason, not an error. Ranges are given out per nominal epoch by the same rule as the
replay, so a log sent as lines gives the replay's ranges.
"""

from __future__ import annotations

import socket
import threading
from collections import Counter
from collections.abc import Iterator, Sequence

from coplane.gtime import GpsTime
from coplane.live.status import SourceStatus
from coplane.recording.csvfiles import DEFAULT_MAX_UWB_RANGE_M, UWB_COLUMNS, RowError, uwb_range
from coplane.recording.model import UwbRange
from coplane.recording.problems import Problems

MAX_BUFFERED = 10_000  # ranges waiting for their epoch; beyond this the oldest are dropped (counted)
MAX_LINE = 256  # bytes: a longer line is garbage, not a range
DATAGRAM = 65535


class UwbInput:
    """One vehicle's UWB ranges from a line stream, lined up by nominal epoch."""

    def __init__(
        self,
        vehicle_id: str,
        fleet_vehicles: Sequence[str],
        problems: Problems,
        max_range_m: float = DEFAULT_MAX_UWB_RANGE_M,
    ) -> None:
        self.vehicle_id = vehicle_id
        self.vehicles = set(fleet_vehicles)
        self.problems = problems
        self.max_range_m = max_range_m
        self.counts: Counter[str] = Counter()
        self.pending: list[UwbRange] = []
        self.latest: GpsTime | None = None  # the newest range time seen (any vehicle)
        self.lines = 0
        self._partial = b""

    def feed_text(self, data: bytes, where: str, final: bool = False) -> None:
        """Lines from a stream (a line cut between two chunks is kept until its end arrives)."""
        buf = self._partial + data
        lines = buf.split(b"\n")
        self._partial = b"" if final else lines.pop()
        if len(self._partial) > MAX_LINE:
            self._bad(where, "malformed-row", f"{len(self._partial)} bytes without a line end")
            self._partial = b""
        for raw in lines:
            self._line(raw, where)

    def feed_datagram(self, data: bytes, where: str) -> None:
        """One UDP datagram: whole lines only (a datagram does not continue the previous one)."""
        for raw in data.split(b"\n"):
            self._line(raw, where)

    def _bad(self, where: str, kind: str, reason: str) -> None:
        self.problems.add(where, self.lines, kind, f"UWB line: {reason}: skipped")

    def _line(self, raw: bytes, where: str) -> None:
        text = raw.decode("utf-8", errors="replace").strip()
        if not text or text.startswith("#"):
            return
        self.lines += 1
        if len(raw) > MAX_LINE:
            self._bad(where, "malformed-row", f"{len(raw)} bytes, longer than {MAX_LINE}")
            return
        fields = [f.strip() for f in text.split(",")]
        if [f.lower() for f in fields] == list(UWB_COLUMNS):
            return  # a header (a uwb.csv sent as is)
        if len(fields) != len(UWB_COLUMNS):
            self._bad(where, "malformed-row", f"{len(fields)} fields, expected {','.join(UWB_COLUMNS)}")
            return
        try:
            r = uwb_range(dict(zip(UWB_COLUMNS, fields, strict=True)), self.vehicles, self.max_range_m)
        except RowError as exc:
            self._bad(where, exc.kind, str(exc))
            return
        if self.latest is None or r.time > self.latest:
            self.latest = r.time
        if r.a != self.vehicle_id:
            self.counts["to-me" if r.b == self.vehicle_id else "other-vehicles"] += 1
            return
        if len(self.pending) >= MAX_BUFFERED:
            self.pending.pop(0)
            self.counts["dropped-buffer-full"] += 1
        self.pending.append(r)
        self.counts["kept"] += 1

    def take(self, t: GpsTime, interval_s: float, tolerance: float = 0.1) -> list[UwbRange]:
        """This vehicle's ranges of nominal epoch `t` (nearest nominal epoch within `tolerance` x
        interval, first range per pair), forgetting everything up to `t`."""
        out: list[UwbRange] = []
        seen: set[tuple[str, str]] = set()
        keep: list[UwbRange] = []
        for r in self.pending:
            n = r.time.round_to(interval_s)
            if n > t:
                keep.append(r)
            elif n == t and abs(r.time - t) <= tolerance * interval_s and r.pair not in seen:
                seen.add(r.pair)
                out.append(r)
        self.counts["late"] += sum(1 for r in self.pending if r.time.round_to(interval_s) < t)
        self.pending = keep
        return out


class UwbUdpSource:
    """UWB lines over UDP: each datagram yielded whole (one or more lines)."""

    def __init__(self, host: str, port: int, name: str | None = None) -> None:
        self.host, self.port = host, port
        self.status = SourceStatus(name or f"udp://{host}:{port}")
        self.datagrams = True  # LiveInputs feeds these with feed_datagram

    def chunks(self, stop: threading.Event) -> Iterator[bytes]:
        """Datagrams until `stop` (a port that cannot be bound is recorded in status, not raised)."""
        try:
            sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            sock.bind((self.host, self.port))
        except OSError as exc:
            self.status.down(f"cannot bind udp {self.host}:{self.port}: {exc.strerror or exc}")
            return
        sock.settimeout(0.2)
        self.status.up()
        try:
            while not stop.is_set():
                try:
                    data = sock.recv(DATAGRAM)
                except TimeoutError:
                    continue
                if data:
                    self.status.data(len(data))
                    yield data
        finally:
            sock.close()
            self.status.connected = False
