"""A live vehicle's inputs: its receiver stream, the base corrections and its UWB ranges, each
read by its own thread, decoded and lined up by nominal epoch on the agent's thread.

Reader threads only move bytes (bounded queues: a file source is throttled to the agent's pace,
a live stream that outruns the agent is counted, not buffered without end); all decoding happens
on the agent's thread, so the navigation data the vehicle step reads is never written while it
is read.

Lockstep (a log replayed through the live path): before epoch t is processed, the base and UWB
streams are read until they have passed t or ended, so the answers equal the replay's. Realtime
(a receiver on the road): what has arrived is used; the base epoch of t is waited for at most
`align_wait_s`, else the newest base epoch not older than `max_correction_age_s` is used and its
age reported (`SppReport.dgnss_age_s`); older corrections are dropped and counted.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from coplane.gnss.dgnss import DgnssCorrections
from coplane.gnss.epoch_solver import base_corrections
from coplane.gtime import GpsTime
from coplane.live.decode import GnssStreamDecoder
from coplane.live.sources import FileSource, SerialSource, TcpSource
from coplane.live.status import ByteSource, SourceStatus
from coplane.live.urls import SourceUrl
from coplane.live.uwb import UwbInput
from coplane.recording.csvfiles import DEFAULT_MAX_UWB_RANGE_M
from coplane.recording.model import NavData, ObsEpoch, UwbRange
from coplane.recording.problems import Problems
from coplane.typing import AnyArray

log = logging.getLogger("coplane.live")
END = b""  # a reader thread's last item: its source ended (files) or stop was set
QUEUE_CHUNKS = 64


def open_source(url: SourceUrl) -> ByteSource:
    """The transport a validated URL names."""
    name = url.redacted()
    if url.transport == "file":
        assert url.path is not None
        return FileSource(url.path, name=name)
    if url.transport == "tcp":
        assert url.host is not None and url.port is not None
        return TcpSource(url.host, url.port, name=name)
    if url.transport == "serial":
        assert url.path is not None and url.baud is not None
        return SerialSource(url.path, url.baud, name=name)
    if url.transport == "ntrip":
        from coplane.live.ntrip import NtripSource

        assert url.host is not None and url.port is not None and url.mountpoint is not None
        return NtripSource(
            url.host, url.port, url.mountpoint, url.user, url.password, name=name, version=url.version
        )
    if url.transport == "udp":
        from coplane.live.uwb import UwbUdpSource

        assert url.port is not None
        return UwbUdpSource(url.host or "0.0.0.0", url.port, name=name)
    raise ValueError(f"no transport for {name}")  # parse_source accepts none other


class _Rejoined:
    """Queued before the first chunk of a new connection (in order with the data)."""


REJOINED = _Rejoined()


class Feed:
    """One source read on its own thread into a bounded queue (END when it ends).

    `on_rejoin` is called, on the reading thread of `get`, where a new connection's bytes begin:
    its decoder drops what it held of the old connection (a half frame, a partial epoch)."""

    def __init__(self, source: ByteSource, on_rejoin: Callable[[], None] | None = None) -> None:
        self.source = source
        self.on_rejoin = on_rejoin
        self.rejoins = 0
        self.queue: queue.Queue[bytes | _Rejoined] = queue.Queue(QUEUE_CHUNKS)
        self.ended = False
        self.thread: threading.Thread | None = None

    @property
    def status(self) -> SourceStatus:
        return self.source.status

    def start(self, stop: threading.Event) -> None:
        self.thread = threading.Thread(target=self._run, args=(stop,), name=self.status.name, daemon=True)
        self.thread.start()

    def _run(self, stop: threading.Event) -> None:
        connects = 1
        try:
            for data in self.source.chunks(stop):
                if self.status.connects > connects:  # bytes of a new connection from here on
                    connects = self.status.connects
                    self._put(REJOINED, stop)
                self._put(data, stop)
        except Exception as exc:  # a transport bug must end this feed visibly, not the agent
            self.status.down(f"reader failed: {exc!r}")
            log.exception("live source reader failed", extra={"source": self.status.name})
        finally:
            while True:  # END must get through, even to a full queue the agent no longer reads
                try:
                    self.queue.put(END, timeout=0.2)
                    break
                except queue.Full:
                    if stop.is_set():
                        break

    def _put(self, item: bytes | _Rejoined, stop: threading.Event) -> None:
        while not stop.is_set():
            try:
                self.queue.put(item, timeout=0.2)
                return
            except queue.Full:
                continue

    def get(self, timeout: float | None) -> bytes | None:
        """The next chunk (END at the end), or None if none came within `timeout` (0: no wait)."""
        if self.ended:
            return END
        try:
            data = self.queue.get(timeout=timeout) if timeout else self.queue.get_nowait()
        except queue.Empty:
            return None
        if isinstance(data, _Rejoined):
            self.rejoins += 1
            if self.on_rejoin is not None:
                self.on_rejoin()
            return None
        if data == END:
            self.ended = True
        return data


@dataclass
class LiveOptions:
    interval_s: float
    lockstep: bool = False
    max_correction_age_s: float = 30.0  # RTKLIB's default `maxage` for DGNSS
    align_wait_s: float = 0.3  # realtime: how long epoch t waits for the base's and UWB's t
    uwb_tolerance: float = 0.1  # as the replay: a range belongs to the epoch within 0.1 interval


class LiveInputs:
    """The receiver, base and UWB feeds of one vehicle, decoded on the caller's thread."""

    def __init__(
        self,
        vehicle_id: str,
        fleet_vehicles: Sequence[str],
        gnss: SourceUrl,
        nav: NavData,
        options: LiveOptions,
        base: SourceUrl | None = None,
        base_position_ecef_m: Sequence[float] | None = None,
        uwb: SourceUrl | None = None,
        uwb_max_range_m: float | None = None,
    ) -> None:
        self.o = options
        self.nav = nav
        self.problems = Problems(keep=200)
        self.counts: Counter[str] = Counter()
        self.gnss = Feed(open_source(gnss), on_rejoin=lambda: self.rover.rejoin())
        self.rover = GnssStreamDecoder(
            "rtcm3" if gnss.format == "rtcm3" else "ubx",
            gnss.redacted(),
            nav,
            self.problems,
            mid_stream=gnss.transport != "file",
        )
        self.base_feed = (
            Feed(open_source(base), on_rejoin=lambda: self.base.rejoin() if self.base is not None else None)
            if base is not None
            else None
        )
        self.base = (
            GnssStreamDecoder(
                "rtcm3", base.redacted(), nav, self.problems, mid_stream=base.transport != "file"
            )
            if base is not None
            else None
        )
        self.base_position: AnyArray | None = (
            np.asarray(base_position_ecef_m, dtype=float) if base_position_ecef_m is not None else None
        )
        self.base_epochs: dict[GpsTime, ObsEpoch] = {}
        self._corr: tuple[GpsTime, DgnssCorrections | None] | None = None
        self.uwb_feed = Feed(open_source(uwb)) if uwb is not None else None
        self.uwb = (
            UwbInput(
                vehicle_id, list(fleet_vehicles), self.problems, uwb_max_range_m or DEFAULT_MAX_UWB_RANGE_M
            )
            if uwb is not None
            else None
        )
        self.uwb_where = uwb.redacted() if uwb is not None else ""
        self.last_age_s: float | None = None
        self._ready: list[ObsEpoch] = []

    @property
    def feeds(self) -> list[Feed]:
        return [f for f in (self.gnss, self.base_feed, self.uwb_feed) if f is not None]

    def start(self, stop: threading.Event) -> None:
        for f in self.feeds:
            f.start(stop)

    # -- the receiver ---------------------------------------------------------------------------
    def next_epoch(self, timeout: float) -> ObsEpoch | bytes | None:
        """The receiver's next epoch; None if none completed within `timeout`; END when the
        receiver stream has ended (a file) and every epoch was given out."""
        deadline = time.monotonic() + timeout
        while not self._ready:
            data = self.gnss.get(max(0.0, deadline - time.monotonic()) or 0.01)
            if data is None:
                if time.monotonic() >= deadline:
                    return None
                continue
            self._ready += self.rover.feed(data, final=data == END)
            if data == END and not self._ready:
                return END
        return self._ready.pop(0)

    # -- base corrections -----------------------------------------------------------------------
    def _pump_base(self, until: GpsTime | None, deadline: float) -> None:
        """Decode base bytes: all that has arrived, and (lockstep, or realtime until `deadline`)
        more until the base has passed `until`."""
        assert self.base_feed is not None and self.base is not None
        while True:
            passed = until is None or (self.base.last is not None and self.base.last >= until)
            wait = 0.0 if passed else max(0.0, deadline - time.monotonic())
            if self.o.lockstep and not passed:
                wait = 0.2
            data = self.base_feed.get(wait)
            if data is None:
                if passed or (not self.o.lockstep and time.monotonic() >= deadline):
                    return
                continue
            for e in self.base.feed(data, final=data == END):
                self.base_epochs[e.time.round_to(self.o.interval_s)] = e
            if data == END:
                return

    def corrections(self, t: GpsTime) -> DgnssCorrections | None:
        """DGNSS corrections for nominal epoch `t`: the base's epoch t, else (realtime) the newest
        one within the age limit; None without a base, a base position or a fresh base epoch."""
        if self.base_feed is None or self.base is None:
            return None
        self._pump_base(t, time.monotonic() + self.o.align_wait_s)
        old = [k for k in self.base_epochs if t - k > self.o.max_correction_age_s]
        for k in old:
            del self.base_epochs[k]
        b = self.base_epochs.get(t)
        if b is None and not self.o.lockstep:
            before = [k for k in self.base_epochs if k <= t]
            b = self.base_epochs[max(before)] if before else None
        if b is None:
            self.counts["no-fresh-base-epoch"] += 1
            return None
        position = self.base_position if self.base_position is not None else self.base.station_ecef_m
        if position is None:
            self.counts["no-base-position"] += 1
            return None
        if self._corr is None or self._corr[0] != b.time:
            self._corr = (b.time, base_corrections(b, position, self.nav))
        self.last_age_s = t - b.time
        return self._corr[1]

    # -- UWB ------------------------------------------------------------------------------------
    def ranges(self, t: GpsTime) -> list[UwbRange]:
        """This vehicle's ranges of nominal epoch `t` (lockstep: once the UWB stream passed it)."""
        if self.uwb_feed is None or self.uwb is None:
            return []
        limit = t + self.o.uwb_tolerance * self.o.interval_s
        deadline = time.monotonic() + self.o.align_wait_s
        while True:
            latest = self.uwb.latest
            passed = latest is not None and latest > limit
            if self.o.lockstep and not passed and not self.uwb_feed.ended:
                data = self.uwb_feed.get(0.2)
            else:
                data = self.uwb_feed.get(0.0 if passed else max(0.0, deadline - time.monotonic()))
            if data is None:
                if self.o.lockstep and not passed and not self.uwb_feed.ended:
                    continue
                if passed or time.monotonic() >= deadline:
                    break
                continue
            if data == END:
                self.uwb.feed_text(b"", self.uwb_where, final=True)
                break
            if getattr(self.uwb_feed.source, "datagrams", False):
                self.uwb.feed_datagram(data, self.uwb_where)
            else:
                self.uwb.feed_text(data, self.uwb_where)
        return self.uwb.take(t, self.o.interval_s, self.o.uwb_tolerance)

    def status(self) -> dict[str, object]:
        """What the agent logs and reports: each source, epochs, correction age, bad input."""
        return {
            "sources": [f.status.snapshot() for f in self.feeds],
            "epochs": self.rover.epochs,
            "frames": self.rover.frames,
            "dgnss_age_s": self.last_age_s,
            "counts": dict(self.counts),
            "uwb": dict(self.uwb.counts) if self.uwb is not None else {},
            "problems": dict(self.problems.counts),
        }
