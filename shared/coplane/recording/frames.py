"""Finding UBX and RTCM 3 frames in a receiver log that may be garbled.

Why not the libraries' stream readers: pyubx2's UBXReader and pyrtcm's RTCMReader trust the
length field of a frame whose checksum then fails, so one flipped length bit swallows the
frames behind it. Here a frame is accepted only when its checksum (UBX Fletcher-8, RTCM CRC-24Q,
computed by the libraries' own helpers) holds; otherwise the search resumes one byte after the
false sync, so the next good frame is found wherever it starts. Each run of bytes that belongs to
no good frame becomes one `Skipped` (offset, length, reason), so a garbled frame costs itself
and never its neighbours. Decoding the frame is the libraries' job (coplane.recording.ubx, rtcm3).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass

from pyrtcm.rtcmhelpers import calc_crc24q
from pyubx2.ubxhelpers import calc_checksum

UBX_SYNC = b"\xb5\x62"
RTCM_SYNC = b"\xd3"


@dataclass(frozen=True, slots=True)
class Frame:
    offset: int
    raw: bytes


@dataclass(frozen=True, slots=True)
class Skipped:
    """Bytes outside any good frame; `ascii` when they are printable text (NMEA between frames)."""

    offset: int
    length: int
    reason: str
    ascii: bool = False


# A check answers (frame length, None) for a good frame at i, (0, why) for a false sync, or
# (INCOMPLETE, why) when the frame may still be good but runs past the bytes seen so far.
INCOMPLETE = -1
MAX_GARBAGE = 65536  # a stream's garbage run is reported in pieces of at most this many bytes
Check = Callable[[bytes, int], tuple[int, str | None]]


def _ubx_check(data: bytes, i: int) -> tuple[int, str | None]:
    """Is there a good UBX frame at i?"""
    if i + 8 > len(data):
        return INCOMPLETE, "truncated frame at the end of the file"
    n = 8 + int.from_bytes(data[i + 4 : i + 6], "little")
    if i + n > len(data):
        return INCOMPLETE, f"frame length {n} runs past the end of the file"
    if calc_checksum(data[i + 2 : i + n - 2]) != data[i + n - 2 : i + n]:
        return 0, "checksum mismatch"
    return n, None


def _rtcm_check(data: bytes, i: int) -> tuple[int, str | None]:
    """Is there a good RTCM 3 frame at i?"""
    if i + 1 < len(data) and data[i + 1] & 0xFC:
        return 0, "reserved header bits set"
    if i + 6 > len(data):
        return INCOMPLETE, "truncated frame at the end of the file"
    n = 6 + ((data[i + 1] & 0x03) << 8 | data[i + 2])
    if i + n > len(data):
        return INCOMPLETE, f"frame length {n} runs past the end of the file"
    if calc_crc24q(data[i : i + n]) != 0:
        return 0, "CRC-24Q mismatch"
    return n, None


def _is_text(b: bytes) -> bool:
    return all(32 <= c < 127 or c in (9, 10, 13) for c in b)


class FrameScanner:
    """The frame search of a file, fed in chunks as a stream delivers them (live receivers).

    A frame that runs past the bytes seen so far is waited for, not skipped; garbage is reported
    as soon as no frame can start in it, so memory stays bounded by one frame (64 KiB for UBX)
    whatever the stream sends. Offsets count from the stream's first byte. Fed all at once with
    `final=True`, it gives exactly the file scan (`ubx_frames`, `rtcm_frames`).
    """

    def __init__(self, sync: bytes, check: Check) -> None:
        self.sync, self.check = sync, check
        self.buf = b""
        self.base = 0  # stream offset of buf[0]
        self.gap = 0  # start (in buf) of the bytes not yet covered by a good frame
        self.i = 0  # where the sync search goes on
        self.reason: str | None = None

    def _skipped(self, start: int, end: int) -> Skipped:
        chunk = self.buf[start:end]
        return Skipped(self.base + start, end - start, self.reason or "bytes between frames", _is_text(chunk))

    def feed(self, data: bytes, final: bool = False) -> list[Frame | Skipped]:
        """Frames and garbage completed by `data`; `final`: the stream ended (flush the rest)."""
        buf = self.buf = self.buf + data if self.buf else bytes(data)
        out: list[Frame | Skipped] = []
        while True:
            j = buf.find(self.sync, self.i)
            if j < 0:
                break
            n, why = self.check(buf, j)
            if n == INCOMPLETE and not final:
                self.i = j
                break
            if n <= 0:
                self.reason = self.reason or why
                self.i = j + 1
                continue
            if j > self.gap:
                out.append(self._skipped(self.gap, j))
            self.reason = None
            out.append(Frame(self.base + j, buf[j : j + n]))
            self.gap = self.i = j + n
        if final:
            if self.gap < len(buf):
                if self.reason is None:
                    self.reason = "bytes after the last frame"
                out.append(self._skipped(self.gap, len(buf)))
            self.gap = self.i = len(buf)
        elif j < 0:
            # no frame can start before the last len(sync)-1 bytes: garbage. It is reported when the
            # next frame ends it (one run per damaged stretch, as in a file) or, to bound memory,
            # once it outgrows MAX_GARBAGE.
            keep = max(self.gap, len(buf) - len(self.sync) + 1)
            if keep - self.gap > MAX_GARBAGE:
                out.append(self._skipped(self.gap, keep))
                self.gap = keep
            self.i = max(self.i, keep)
        cut = min(self.gap, self.i)
        if cut:
            self.buf, self.base = buf[cut:], self.base + cut
            self.gap -= cut
            self.i -= cut
        return out


def ubx_scanner() -> FrameScanner:
    """An incremental UBX frame search (a live receiver stream)."""
    return FrameScanner(UBX_SYNC, _ubx_check)


def rtcm_scanner() -> FrameScanner:
    """An incremental RTCM 3 frame search (a live stream or an NTRIP caster)."""
    return FrameScanner(RTCM_SYNC, _rtcm_check)


def ubx_frames(data: bytes) -> Iterator[Frame | Skipped]:
    """Checksum-good UBX frames in file order, and the garbage between them."""
    return iter(ubx_scanner().feed(data, final=True))


def rtcm_frames(data: bytes) -> Iterator[Frame | Skipped]:
    """CRC-good RTCM 3 frames in file order, and the garbage between them."""
    return iter(rtcm_scanner().feed(data, final=True))
