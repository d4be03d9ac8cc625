"""Receiver bytes in, observation epochs out: UBX and RTCM 3 decoded as a stream delivers them.

The file readers (`recording/ubx.py`, `rtcm3.py`, `sfrbx.py`) and this decoder share the frame
search (`FrameScanner`) and the per-frame decoders, so a stream and the file it was recorded to
give the same epochs and ephemerides. Ephemerides go into the `NavData` the vehicle step reads,
as they complete; bad frames are counted in `problems` (by kind) and cost only themselves.

Epoch time is the receiver's own tag: RAWX rcvTow + week (rollover resolved by the receiver);
MSM time of week resolved to the week nearest the previous epoch (first: the median week of the
BeiDou 1042s seen so far, as the file reader takes the median of a log's 1042s, else that of the
ephemerides already held, `NavData.reference_time`, else the clock), so a stream that crosses a
week boundary keeps counting. Before the first epoch, 1042s set the week once two satellites'
agree within a week: one well-formed 1042 of another week must not move every epoch by weeks.
"""

from __future__ import annotations

import itertools
import statistics
from collections.abc import Mapping, Sequence
from typing import Any, Literal

import numpy as np

from coplane.gtime import SECONDS_PER_WEEK, GpsTime, bdt_to_gpst
from coplane.recording.broadcast import nearest_week, today
from coplane.recording.frames import Frame, FrameScanner, rtcm_scanner, ubx_scanner
from coplane.recording.model import NavData, ObsEpoch
from coplane.recording.problems import Problems
from coplane.recording.rinex_obs import DEFAULT_SIGNALS, DEFAULT_SYSTEMS, SignalCodes
from coplane.recording.rtcm3 import Msm, RtcmReader
from coplane.recording.rtcm3_ephemeris import decode_ephemeris
from coplane.recording.sfrbx import SfrbxDecoder
from coplane.recording.ubx import RawxReader
from coplane.typing import AnyArray

Format = Literal["ubx", "rtcm3"]
_RAWX = b"\x02\x15"  # RXM-RAWX class/id
MAX_HELD = 4096  # navigation frames kept while the stream has not yet told the week


class GnssStreamDecoder:
    """One receiver stream (UBX or RTCM 3): `feed(bytes)` -> the epochs those bytes complete."""

    def __init__(
        self,
        fmt: Format,
        where: str,
        nav: NavData,
        problems: Problems,
        signals: Mapping[str, SignalCodes] | None = None,
        systems: Sequence[str] = DEFAULT_SYSTEMS,
        mid_stream: bool = False,
    ) -> None:
        """`mid_stream`: the bytes start wherever the stream was when we joined (a socket, a
        caster, a serial port, not a file): the first RTCM epoch may lack the MSMs sent before we
        joined, so it is dropped (counted `partial-first-epoch`) unless the end of an earlier
        epoch was seen first. UBX epochs are one RAWX each, never partial."""
        self.fmt, self.where, self.nav, self.problems = fmt, where, nav, problems
        self._synced = not mid_stream  # an epoch's first MSM is known to follow a closed epoch
        sig = dict(DEFAULT_SIGNALS if signals is None else signals)
        self.frames = 0
        self.epochs = 0
        self.station_ecef_m: AnyArray | None = None  # from RTCM 1005/1006
        self.last: GpsTime | None = None
        self._pending: list[Msm] = []
        # Broadcast GPS navigation carries a 10-bit week: it is decoded once the stream gave a full
        # time (a RAWX epoch, a BeiDou 1042, else the clock at the first MSM epoch), so an old log
        # replayed as a stream resolves its week as the file reader does. Bounded: at MAX_HELD the
        # clock is taken.
        self._held: list[Any] = []
        self._bds_toes: dict[int, GpsTime] = {}  # BeiDou satellite -> its 1042's toe, until the week is set
        self.reference: GpsTime | None = None
        self.scanner: FrameScanner
        if fmt == "ubx":
            self.scanner = ubx_scanner()
            self.rawx = RawxReader(where, problems, sig, systems)
            self.sfrbx = SfrbxDecoder(where, problems, nav, today())
        else:
            self.scanner = rtcm_scanner()
            self.rtcm = RtcmReader(where, problems, sig, systems)

    def rejoin(self) -> None:
        """The stream reconnected: what was held of the old connection (a frame cut by the drop,
        an epoch's first MSMs) cannot be completed by the new bytes, and the first RTCM epoch of
        the new connection may lack MSMs sent before it (dropped as after the first join)."""
        old = self.scanner
        for item in old.feed(b"", final=True):  # the old connection's tail: counted as garbage
            if self.fmt == "ubx":
                self._ubx(item)
            else:
                self._rtcm(item)
        self.scanner = ubx_scanner() if self.fmt == "ubx" else rtcm_scanner()
        self.scanner.base = old.base + len(old.buf)  # offsets keep counting the stream's bytes
        if self._pending:
            self.problems.add(
                self.where,
                None,
                "partial-epoch",
                "epoch cut by a reconnect dropped",
                offset=self._pending[0].offset,
            )
            self._pending = []
        if self.fmt == "rtcm3":
            self._synced = False

    def feed(self, data: bytes, final: bool = False) -> list[ObsEpoch]:
        """Decode `data`; `final`: the stream ended (flush a partial frame and the last epoch)."""
        out: list[ObsEpoch] = []
        for item in self.scanner.feed(data, final):
            if isinstance(item, Frame):
                self.frames += 1
            ep = self._ubx(item) if self.fmt == "ubx" else self._rtcm(item)
            if ep is not None:
                out.append(ep)
        if final and self._pending:
            out.extend(self._flush())
        self.epochs += len(out)
        return out

    # -- UBX ------------------------------------------------------------------------------------
    def _ubx(self, item: Any) -> ObsEpoch | None:
        if not isinstance(item, Frame):
            if not item.ascii:  # NMEA between UBX frames is another protocol, not damage
                self.problems.add(
                    self.where, None, "garbled-frame", f"{item.length} byte(s) skipped: {item.reason}",
                    offset=item.offset,
                )  # fmt: skip
            return None
        if item.raw[2:4] == _RAWX:
            ep = self.rawx.epoch(item)
            if ep is not None:
                self._set_reference(ep.time)
                self.last = ep.time
            return ep
        if self.reference is None and len(self._held) < MAX_HELD:
            self._held.append(item)
        else:
            self._set_reference(today())
            self.sfrbx.add(item)
        return None

    def _set_reference(self, t: GpsTime) -> None:
        """From now on resolve broadcast weeks near `t`; decode what waited for it."""
        if self.fmt == "ubx":
            self.sfrbx.reference = t
        if self.reference is not None:
            self.reference = t
            return
        self.reference = t
        held, self._held = self._held, []
        for h in held:
            if self.fmt == "ubx":
                self.sfrbx.add(h)
            else:
                self._ephemeris(*h)

    # -- RTCM 3 ---------------------------------------------------------------------------------
    def _rtcm(self, item: Any) -> ObsEpoch | None:
        got = self.rtcm.take(item)
        if got is None:
            return None
        if not isinstance(got, Msm):
            self._rtcm_other(*got)
            return None
        out = None
        if self._pending and got.tow_ms != self._pending[0].tow_ms:
            out = self._close()  # a stream without the multiple-message bit: the next epoch began
        self._pending.append(got)
        if int(getattr(got.msg, "DF393", 0)) == 0:  # the last MSM of its epoch
            return self._close() or out
        return out

    def _close(self) -> ObsEpoch | None:
        """The pending MSMs as an epoch, if it is known to be whole."""
        if not self._synced:
            self._synced = True
            msms, self._pending = self._pending, []
            self.problems.add(
                self.where, None, "partial-first-epoch",
                "first epoch after joining the stream dropped: its first MSMs may have gone before",
                offset=msms[0].offset,
            )  # fmt: skip
            return None
        return self._close_epoch()

    def _close_epoch(self) -> ObsEpoch | None:
        msms, self._pending = self._pending, []
        if self.reference is None:
            self._set_reference(self._bds_reference() or self.nav.reference_time() or today())
        ref = self.last or self.reference or today()
        t = nearest_week(msms[0].tow_ms / 1000.0, ref)
        if self.last is not None and t <= self.last:
            self.problems.add(
                self.where, None, "non-monotonic-time", f"epoch {t} is not after {self.last}: skipped",
                offset=msms[0].offset,
            )  # fmt: skip
            return None
        self.last = t
        return self.rtcm.epoch(t, msms)

    def _flush(self) -> list[ObsEpoch]:
        ep = self._close()
        return [ep] if ep is not None else []

    def _rtcm_other(self, offset: int, msg: Any) -> None:
        ident = msg.identity
        if ident in ("1005", "1006"):
            try:
                xyz = np.array([float(msg.DF025), float(msg.DF026), float(msg.DF027)])
            except (AttributeError, TypeError, ValueError) as exc:
                self.problems.add(self.where, None, "malformed-record", f"{ident}: {exc}", offset=offset)
                return
            if not (np.all(np.isfinite(xyz)) and 6.0e6 < float(np.linalg.norm(xyz)) < 6.5e6):
                self.problems.add(
                    self.where, None, "absurd-value", f"{ident}: station at {xyz.tolist()} m is not on the Earth",
                    offset=offset,
                )  # fmt: skip
                return
            self.station_ecef_m = xyz
            return
        if ident == "1042" and self.reference is None:
            self._bds_week_candidate(msg)
        if self.reference is None and len(self._held) < MAX_HELD:
            self._held.append((offset, msg))
            return
        self._ephemeris(offset, msg)

    def _bds_week_candidate(self, msg: Any) -> None:
        """A 1042's toe as a candidate for the stream's week (a 13-bit BDT week, unlike a 1019's
        10 bits); the week is set once two satellites' toes lie within a week of each other."""
        try:  # a bad one: decode_ephemeris names what is wrong with it when it is decoded
            self._bds_toes[int(msg.DF488)] = bdt_to_gpst(int(msg.DF489), float(msg.DF505))
        except (AttributeError, TypeError, ValueError, OverflowError):
            return
        toes = sorted(self._bds_toes.values())
        if any(b - a <= SECONDS_PER_WEEK for a, b in itertools.pairwise(toes)):
            self._set_reference(statistics.median_low(toes))

    def _bds_reference(self) -> GpsTime | None:
        """The median toe of the 1042s seen before the week was set (None: none seen)."""
        return statistics.median_low(self._bds_toes.values()) if self._bds_toes else None

    def _ephemeris(self, offset: int, msg: Any) -> None:
        ident = msg.identity
        try:
            self.nav.add(decode_ephemeris(msg, self.last or self.reference or today()))
        except (ValueError, AttributeError) as exc:
            self.problems.add(
                self.where,
                None,
                "malformed-record",
                f"ephemeris {ident} does not decode: {exc}",
                offset=offset,
            )
