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


def _ubx_check(data: bytes, i: int) -> tuple[int, str | None]:
    """(frame length, None) for a good UBX frame at i, else (0, why not)."""
    if i + 8 > len(data):
        return 0, "truncated frame at the end of the file"
    n = 8 + int.from_bytes(data[i + 4 : i + 6], "little")
    if i + n > len(data):
        return 0, f"frame length {n} runs past the end of the file"
    if calc_checksum(data[i + 2 : i + n - 2]) != data[i + n - 2 : i + n]:
        return 0, "checksum mismatch"
    return n, None


def _rtcm_check(data: bytes, i: int) -> tuple[int, str | None]:
    """(frame length, None) for a good RTCM 3 frame at i, else (0, why not)."""
    if i + 6 > len(data):
        return 0, "truncated frame at the end of the file"
    if data[i + 1] & 0xFC:
        return 0, "reserved header bits set"
    n = 6 + ((data[i + 1] & 0x03) << 8 | data[i + 2])
    if i + n > len(data):
        return 0, f"frame length {n} runs past the end of the file"
    if calc_crc24q(data[i : i + n]) != 0:
        return 0, "CRC-24Q mismatch"
    return n, None


def _is_text(b: bytes) -> bool:
    return all(32 <= c < 127 or c in (9, 10, 13) for c in b)


def _scan(
    data: bytes, sync: bytes, check: Callable[[bytes, int], tuple[int, str | None]]
) -> Iterator[Frame | Skipped]:
    gap = 0  # start of the bytes not yet covered by a good frame
    reason: str | None = None
    i = 0
    while True:
        j = data.find(sync, i)
        if j < 0:
            break
        n, why = check(data, j)
        if n == 0:
            reason = reason or why
            i = j + 1
            continue
        if j > gap:
            chunk = data[gap:j]
            yield Skipped(gap, j - gap, reason or "bytes between frames", _is_text(chunk))
        reason = None
        yield Frame(j, data[j : j + n])
        gap = i = j + n
    if gap < len(data):
        chunk = data[gap:]
        yield Skipped(gap, len(chunk), reason or "bytes after the last frame", _is_text(chunk))


def ubx_frames(data: bytes) -> Iterator[Frame | Skipped]:
    """Checksum-good UBX frames in file order, and the garbage between them."""
    return _scan(data, UBX_SYNC, _ubx_check)


def rtcm_frames(data: bytes) -> Iterator[Frame | Skipped]:
    """CRC-good RTCM 3 frames in file order, and the garbage between them."""
    return _scan(data, RTCM_SYNC, _rtcm_check)
