"""Source URLs of a live agent, parsed and validated before anything connects.

    ubx+tcp://HOST:PORT        rtcm3+tcp://HOST:PORT        receiver (or serial bridge) on TCP
    ubx+serial:///dev/ttyACM0?baud=115200                    receiver on a serial port
    ubx+file:///path/log.ubx   file:///path/log.rtcm3        a log (format from the extension)
    ntrip://[user[:password]@]HOST[:PORT]/MOUNT              RTCM 3 from an NTRIP caster
    udp://[HOST]:PORT          serial:///dev/ttyUSB0?baud=   UWB range lines (docs/live.md)
    file:///path/uwb.csv                                     UWB lines from a log

A URL that cannot work is a ConfigError naming the option, the URL (password hidden) and the part
that is wrong, so a typo is found at start and not as a silent reconnect loop.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal
from urllib.parse import parse_qs, unquote, urlsplit

from coplane.errors import ConfigError

Transport = Literal["file", "tcp", "serial", "ntrip", "udp"]
Format = Literal["ubx", "rtcm3", "uwb"]
Role = Literal["gnss", "base", "uwb"]

MAX_PORT = 65535  # TCP and UDP port numbers are 16 bits; 0 asks the OS for a free one

EXTENSIONS: dict[str, Format] = {
    ".ubx": "ubx",
    ".rtcm3": "rtcm3",
    ".rtcm": "rtcm3",
    ".csv": "uwb",
    ".txt": "uwb",
}
FORMATS_OF: dict[Role, tuple[Format, ...]] = {"gnss": ("ubx", "rtcm3"), "base": ("rtcm3",), "uwb": ("uwb",)}
TRANSPORTS_OF: dict[Role, tuple[Transport, ...]] = {
    "gnss": ("tcp", "serial", "file", "ntrip"),
    "base": ("tcp", "serial", "file", "ntrip"),
    "uwb": ("udp", "serial", "file"),
}
EXAMPLES: dict[Role, str] = {
    "gnss": "ubx+tcp://HOST:PORT, rtcm3+serial:///dev/ttyACM0?baud=115200, ubx+file:///path/log.ubx",
    "base": "ntrip://user:pass@HOST:2101/MOUNT, rtcm3+tcp://HOST:PORT, rtcm3+file:///path/base.rtcm3",
    "uwb": "udp://:5600, serial:///dev/ttyUSB0?baud=115200, file:///path/uwb.csv",
}
DEFAULT_BAUD = 115200
MAX_BAUD = 4_000_000
NTRIP_PORT = 2101


@dataclass(frozen=True)
class SourceUrl:
    text: str
    transport: Transport
    format: Format
    host: str | None = None
    port: int | None = None
    path: str | None = None  # file path or serial device
    baud: int | None = None
    user: str | None = None
    password: str | None = None
    mountpoint: str | None = None
    version: int = 2  # NTRIP protocol version (ntrip:// only)

    def redacted(self) -> str:
        """The URL with the password hidden: the only form that goes into logs and errors."""
        return _redact(self.text)

    def __str__(self) -> str:
        return self.redacted()

    def __repr__(self) -> str:  # a dataclass repr would print the password
        return f"SourceUrl({self.redacted()!r})"


def _redact(text: str) -> str:
    scheme, sep, rest = text.partition("://")
    if not sep:
        return text
    netloc, slash, tail = rest.partition("/")
    if "@" in netloc:
        cred, _, host = netloc.rpartition("@")
        user = cred.split(":", 1)[0]
        netloc = f"{user}:***@{host}" if ":" in cred else f"{user}@{host}"
    return f"{scheme}{sep}{netloc}{slash}{tail}"


def parse_source(text: str, *, option: str, role: Role) -> SourceUrl:
    """A validated source URL for `role` ("gnss", "base" or "uwb"), given as `option` (for errors)."""
    shown = _redact(text)

    def bad(part: str) -> ConfigError:
        return ConfigError(f"{option} {shown}: {part} (expected e.g. {EXAMPLES[role]})")

    if "://" not in text and not text.startswith("file:"):
        raise bad("not a URL: no scheme")
    scheme = text.split(":", 1)[0].lower()
    fmt_given, _, transport_name = scheme.rpartition("+")
    if transport_name not in ("file", "tcp", "serial", "ntrip", "udp"):
        raise bad(f"unknown transport {transport_name!r}; one of {', '.join(TRANSPORTS_OF[role])}")
    transport: Transport = transport_name  # type: ignore[assignment]
    if transport not in TRANSPORTS_OF[role]:
        raise bad(f"transport {transport!r} is not for {role} input; one of {', '.join(TRANSPORTS_OF[role])}")
    if fmt_given and fmt_given not in ("ubx", "rtcm3", "uwb"):
        raise bad(f"unknown format {fmt_given!r}; one of {', '.join(FORMATS_OF[role])}")
    try:
        u = urlsplit(text)
        port = u.port
    except ValueError as exc:
        raise bad(f"port: {exc}") from None
    query = parse_qs(u.query, keep_blank_values=True)
    allowed = {"serial": {"baud"}, "ntrip": {"version"}}.get(transport, set())
    unknown = sorted(set(query) - allowed)
    if unknown:
        raise bad(
            f"unknown query parameter {unknown[0]!r}"
            + (f"; allowed: {', '.join(sorted(allowed))}" if allowed else "")
        )

    fmt: Format | None = fmt_given or None  # type: ignore[assignment]
    host, path, baud, user, password, mount = None, None, None, None, None, None
    ntrip_version = 2
    if transport in ("tcp", "ntrip", "udp"):
        host = u.hostname or None
        if host is None and transport != "udp":
            raise bad("missing host")
        if transport == "ntrip" and port is None:
            port = NTRIP_PORT
        if port is None:
            raise bad("missing port (HOST:PORT)")
        if not 1 <= port <= MAX_PORT:
            raise bad(f"port {port} outside 1..{MAX_PORT}")
        if u.path not in ("", "/") and transport != "ntrip":
            raise bad(f"unexpected path {u.path!r} after the port")
        if transport == "ntrip":
            mount = unquote(u.path.lstrip("/"))
            if not mount or "/" in mount:
                raise bad("missing or bad mountpoint (ntrip://HOST:PORT/MOUNT)")
            user = unquote(u.username) if u.username else None
            password = unquote(u.password) if u.password is not None else None
            fmt = fmt or "rtcm3"
            version = query.get("version", ["2"])[-1]
            if version not in ("1", "2"):
                raise bad(f"version {version!r}: NTRIP version is 1 or 2")
            ntrip_version = int(version)
        elif u.username or u.password:
            raise bad("credentials are only for ntrip://")
    else:  # file, serial: the path is everything after the scheme
        path = unquote(u.path) if u.netloc in ("", "localhost") else None
        if path is None:
            raise bad(f"host {u.netloc!r} in a {transport} URL; use {transport}:///absolute/path")
        if not path:
            raise bad("empty path")
        if transport == "serial":
            raw = query.get("baud", [str(DEFAULT_BAUD)])[-1]
            if not raw.isdigit() or not 0 < int(raw) <= MAX_BAUD:
                raise bad(f"baud {raw!r}: a whole number of bit/s, 1..{MAX_BAUD}")
            baud = int(raw)
        else:
            p = Path(path)
            if not p.is_file():
                raise bad(f"file {path} not found")
            fmt = fmt or EXTENSIONS.get(p.suffix.lower())
            if fmt is None:
                raise bad(f"format of {p.name} unknown: name it, e.g. ubx+file:// or rtcm3+file://")
    if role == "uwb":
        fmt = fmt or "uwb"
    if fmt is None:
        raise bad(f"format missing: write {FORMATS_OF[role][0]}+{transport}://...")
    if fmt not in FORMATS_OF[role]:
        raise bad(f"format {fmt!r} is not for {role} input; one of {', '.join(FORMATS_OF[role])}")
    return SourceUrl(text, transport, fmt, host, port, path, baud, user, password, mount, ntrip_version)
