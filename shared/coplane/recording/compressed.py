"""Compressed RINEX as reference-station networks and archives publish it.

A CORS base or a daily BRDC file usually comes gzip- or Unix-compressed (`.gz`, `.Z`), and
observation files also in Hatanaka's Compact RINEX (`.crx`, RINEX 2 `.YYd`), often both
(`.crx.gz`). coplane's readers take them as they come: `open_rinex_text` gives the plain text,
decompressed whole in memory by the `hatanaka` package (RNXCMP's crx2rnx and the archive formats;
bzip2 and zip too), or the file itself when its name says it is plain. `plain_file` writes the
plain copy a program that reads plain RINEX only (RTKLIB's postpos) needs.
"""

from __future__ import annotations

import io
import re
from pathlib import Path
from typing import Literal, TextIO

from coplane.recording.problems import RecordingError

ARCHIVE_SUFFIXES = (".gz", ".z", ".bz2", ".zip")  # lower case: RINEX 2 archives use ".Z"
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
    """The plain content of a compressed file; RecordingError naming it when it cannot be read."""
    import hatanaka  # the reference implementation of Compact RINEX (RNXCMP), wrapped for Python

    try:
        return hatanaka.decompress(path)
    except FileNotFoundError as exc:
        raise RecordingError(f"{path}: no such file") from exc
    except Exception as exc:  # gzip, zlib, bzip2, zip, LZW and crx2rnx each raise their own
        raise RecordingError(f"{path}: cannot decompress ({type(exc).__name__}: {exc})") from exc


def open_rinex_text(path: Path) -> TextIO:
    """A RINEX file as text (latin-1, any line ending), compressed or not."""
    if not is_compressed(path):
        return path.open("r", encoding="latin-1", newline=None)
    return io.StringIO(decompressed(path).decode("latin-1"), newline=None)


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
    """`path` itself when plain, else its decompressed copy in `directory` (same plain name)."""
    if not is_compressed(path):
        return path
    out = directory / plain_name(path.name)
    out.write_bytes(decompressed(path))
    return out
