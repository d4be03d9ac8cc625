"""Compressed RINEX as reference-station networks and archives publish it.

A CORS base or a daily BRDC file usually comes gzip- or Unix-compressed (`.gz`, `.Z`), and
observation files also in Hatanaka's Compact RINEX (`.crx`, RINEX 2 `.YYd`), often both
(`.crx.gz`). coplane's readers take them as they come: `open_rinex_text` gives the plain text, decompressed
in memory (the archive layer streamed up to a bound, Compact RINEX by the `hatanaka` package,
RNXCMP's crx2rnx), or the file itself when its name says it is plain. `plain_file` writes the
plain copy a program that reads plain RINEX only (RTKLIB's postpos) needs.
"""

from __future__ import annotations

import bz2
import contextlib
import io
import re
import zipfile
import zlib
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any, Literal, TextIO

from coplane.recording.problems import RecordingError

ARCHIVE_SUFFIXES = (".gz", ".z", ".bz2", ".zip")  # lower case: RINEX 2 archives use ".Z"
MAX_PLAIN_BYTES = 2 * 2**30  # a day of 1 Hz multi-GNSS observations is a few hundred MB
_CHUNK = 1 << 20
_HEAD = 4096  # enough for a Compact RINEX file's first three lines
_HATANAKA = re.compile(r"(\.crx|\.\d\dd)$")  # RINEX 3 long names, RINEX 2 short names (".21d")


def plain_name(name: str) -> str:
    """The file name once decompressed: without the archive suffix, Compact RINEX as RINEX."""
    lower = name.lower()
    for suffix in ARCHIVE_SUFFIXES:
        if lower.endswith(suffix):
            name, lower = name[: -len(suffix)], lower[: -len(suffix)]
            break
    m = _HATANAKA.search(lower)
    if m is None:
        return name
    plain = ".rnx" if m.group(1) == ".crx" else m.group(1)[:-1] + "o"
    return name[: m.start()] + plain


def is_compressed(path: Path) -> bool:
    """Whether `path`'s name says it is archived or in Compact RINEX."""
    return plain_name(path.name) != path.name


def decompressed(path: Path) -> bytes:
    """The plain content of a compressed file; RecordingError naming it when it cannot be read,
    or when it would exceed `MAX_PLAIN_BYTES` (a crafted archive must not exhaust memory: every
    archive format stops there, see `_unarchive`)."""
    import hatanaka  # the reference implementation of Compact RINEX (RNXCMP), wrapped for Python

    try:
        data = path.read_bytes()
    except OSError as exc:
        raise RecordingError(f"{path}: cannot read ({exc.strerror or exc})") from exc
    try:
        plain = _unarchive(data, path)
        if b"COMPACT RINEX" in plain[:80]:
            plain = hatanaka.crx2rnx(plain)
    except RecordingError:
        raise
    except Exception as exc:  # zlib, bzip2, zip, LZW and crx2rnx each raise their own
        raise RecordingError(f"{path}: cannot decompress ({type(exc).__name__}: {exc})") from exc
    if len(plain) > MAX_PLAIN_BYTES:  # Compact RINEX expands a few times
        raise _too_large(path)
    return plain


def _unarchive(data: bytes, path: Path, head: int | None = None) -> bytes:
    """The archive layer (gzip, bzip2, zip, Unix compress) taken off, by magic bytes as RNXCMP's
    tools do; `head`: only the first that many bytes, decompressing no further than needed.
    hatanaka decompresses archives whole with no bound, so they are streamed here and stop at
    MAX_PLAIN_BYTES: gzip, bzip2 and zip with the standard library's decompressors, Unix compress
    (LZW, which the standard library lacks) with ncompress, hatanaka's own dependency, writing
    into `_BoundedSink`."""
    if data[:2] == b"\x1f\x8b":
        return _bounded(_members(data, b"\x1f\x8b", lambda: zlib.decompressobj(wbits=31), path), path, head)
    if data[:3] == b"BZh":
        return _bounded(_members(data, b"BZh", bz2.BZ2Decompressor, path), path, head)
    if data[:4] == b"PK\x03\x04":
        with zipfile.ZipFile(io.BytesIO(data)) as z:
            names = z.namelist()
            if len(names) != 1:
                raise RecordingError(f"{path}: a zip archive must hold one file, it holds {len(names)}")
            with z.open(names[0]) as f:
                return _bounded(iter(lambda: f.read(_CHUNK), b""), path, head)
    if data[:2] == b"\x1f\x9d":
        import ncompress  # hatanaka's own dependency for LZW

        sink = _BoundedSink(path, head)
        with contextlib.suppress(_HeadFull):  # the head asked for is complete
            ncompress.decompress(data, sink)
        return bytes(sink.out)
    return data[:head]  # Compact RINEX without an archive around it


def _members(data: bytes, magic: bytes, new: Callable[[], Any], path: Path) -> Iterator[bytes]:
    """Every member's output, in chunks (gzip and bzip2 files may be several streams end to end;
    what follows the last one, padding or not, is ignored, as gzip itself does)."""
    while data.startswith(magic):
        d = new()
        while not d.eof:
            chunk = d.decompress(data, _CHUNK)
            data = d.unconsumed_tail if hasattr(d, "unconsumed_tail") else b""
            if chunk:
                yield chunk
            elif not data and (not hasattr(d, "needs_input") or d.needs_input):
                raise RecordingError(f"{path}: cannot decompress (the archive is cut short)")
        data = d.unused_data.lstrip(b"\0")  # trailing padding is not another member


class _HeadFull(Exception):
    """Raised into ncompress's loop once the `head` bytes asked for are written: nothing more is needed."""


class _BoundedSink(io.RawIOBase):
    """A binary stream ncompress writes its output into, chunk by chunk (it has no iterator of
    chunks as zlib and bz2 do): it keeps the first `head` bytes, or all up to MAX_PLAIN_BYTES,
    and stops the decoder with an exception beyond, before the memory is spent."""

    def __init__(self, path: Path, head: int | None) -> None:
        super().__init__()
        self.out = bytearray()
        self._path, self._head = path, head

    def writable(self) -> bool:
        return True

    def write(self, b: Any) -> int:
        self.out += b
        if self._head is not None and len(self.out) >= self._head:
            del self.out[self._head :]
            raise _HeadFull
        if len(self.out) > MAX_PLAIN_BYTES:
            raise _too_large(self._path)
        return len(b)


def _bounded(chunks: Iterable[bytes], path: Path, head: int | None = None) -> bytes:
    """The chunks joined, up to MAX_PLAIN_BYTES (an error beyond), or only their first `head` bytes."""
    out = bytearray()
    for chunk in chunks:
        out += chunk
        if head is not None and len(out) >= head:
            return bytes(out[:head])
        if len(out) > MAX_PLAIN_BYTES:
            raise _too_large(path)
    return bytes(out)


def _too_large(path: Path) -> RecordingError:
    return RecordingError(
        f"{path}: more than {MAX_PLAIN_BYTES / 2**30:g} GiB once decompressed; split it, or "
        "decompress it first if it is genuine"
    )


def open_rinex_text(path: Path) -> TextIO:
    """A RINEX file as text (latin-1, any line ending), compressed or not."""
    if not is_compressed(path):
        return path.open("r", encoding="latin-1", newline=None)
    return io.StringIO(decompressed(path).decode("latin-1"), newline=None)


def first_rinex_line(path: Path) -> str:
    """The `RINEX VERSION / TYPE` line a file would begin with once plain, from its first few kB
    only (a compressed file is not decompressed whole to tell what it is): in Compact RINEX that
    line is the third. RecordingError when a compressed file cannot be read."""
    try:
        with path.open("rb") as f:
            data = f.read() if is_compressed(path) else f.read(_HEAD)
    except OSError as exc:
        raise RecordingError(f"{path}: cannot read ({exc.strerror or exc})") from exc
    try:
        head = _unarchive(data, path, _HEAD) if is_compressed(path) else data
    except RecordingError:
        raise
    except Exception as exc:  # the decompressors' own errors, as in `decompressed`
        raise RecordingError(f"{path}: cannot decompress ({type(exc).__name__}: {exc})") from exc
    lines = head.decode("latin-1").splitlines()
    if lines and "COMPACT RINEX" in lines[0]:
        return lines[2] if len(lines) > 2 else ""
    return lines[0] if lines else ""


def file_format(path: Path) -> Literal["ubx", "rtcm3", "rinex"]:
    """How a recording's file is read, by its name once decompressed (`rover.ubx.gz`: "ubx")."""
    suffix = Path(plain_name(path.name)).suffix.lower()
    return "ubx" if suffix == ".ubx" else "rtcm3" if suffix == ".rtcm3" else "rinex"


def read_log_bytes(path: Path, what: str) -> bytes:
    """A binary receiver log's bytes, decompressed when its name says it is compressed."""
    if is_compressed(path):
        return decompressed(path)
    try:
        return path.read_bytes()
    except OSError as exc:
        raise RecordingError(f"{path}: cannot read {what} file ({exc.strerror or exc})") from exc


def plain_file(path: Path, directory: Path) -> Path:
    """`path` itself when plain, else its decompressed copy in `directory` (made if needed; same
    plain name)."""
    if not is_compressed(path):
        return path
    directory.mkdir(parents=True, exist_ok=True)
    out = directory / plain_name(path.name)
    out.write_bytes(decompressed(path))
    return out
