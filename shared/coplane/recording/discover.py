"""The files of a drive's folder: which are RINEX observation or navigation files or receiver
logs, and what each observation file holds (epochs, interval, satellites, Doppler).

`coplane recording init` (`recording.plan`) describes a folder of them as a fleet recording; this
module only looks. Written here because no RINEX library reads a folder of several receivers'
files as one session; the parsing is coplane's own readers', as for every recording.
"""

from __future__ import annotations

import itertools
import math
import re
import statistics
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from coplane.gtime import GpsTime
from coplane.ids import is_vehicle_id
from coplane.recording.compressed import file_format, first_rinex_line, is_compressed, plain_name
from coplane.recording.logs import log_navigation, log_observations, parse_log
from coplane.recording.model import ObsEpoch, ObsHeader
from coplane.recording.problems import Problems, RecordingError
from coplane.recording.rinex_obs import DEFAULT_SYSTEMS, iter_obs

MAX_FILES = 2000  # a directory tree larger than this is not a drive's folder: refuse, naming it
# where `recording init` writes one receiver's consecutive files joined (recording/splice.py): not
# looked in, or the joined files would be found beside their parts
SPLICED_DIR = "spliced"
NAV_SYSTEMS = ("G", "C", "M")  # navigation files of these systems are merged (M: mixed)


@dataclass(frozen=True)
class ReceiverFile:
    """What a file is: a RINEX observation or navigation file (its version and system, from its
    first line), or a receiver log (`log`: a .ubx or .rtcm3 file, which may hold both)."""

    path: Path
    kind: Literal["obs", "nav", "log", "other"]
    version: float
    system: str  # the header's satellite system letter; RINEX 2 GPS navigation is "G"


def sniff(path: Path) -> ReceiverFile | None:
    """The kind of `path`: a receiver log by its extension, RINEX by its first line (decompressed
    first when its name says it is compressed); None otherwise."""
    if file_format(path) != "rinex":  # a receiver log, plain or archived
        return ReceiverFile(path, "log", 0.0, "")
    try:
        line = first_rinex_line(path)  # a compressed file's first kB, not all of it
    except RecordingError:  # unreadable, or named like a compressed file but not one
        return None if not is_compressed(path) else ReceiverFile(path, "other", 0.0, "unreadable")
    if "RINEX VERSION / TYPE" not in line:
        return None
    try:
        version = float(line[0:9])
    except ValueError:
        return None
    kind_char, system = line[20:21], line[40:41].strip()
    if kind_char == "O":
        return ReceiverFile(path, "obs", version, system or "G")
    if kind_char == "N":  # RINEX 3: system in column 41; RINEX 2 "N": GPS navigation
        return ReceiverFile(path, "nav", version, (system or "G") if version >= 3.0 else "G")
    if kind_char in ("G", "H", "L", "C") and version < 3.0:  # RINEX 2 GLONASS, SBAS, Galileo nav
        return ReceiverFile(path, "nav", version, {"G": "R", "H": "S", "L": "E"}.get(kind_char, kind_char))
    return ReceiverFile(path, "other", version, system)


@dataclass
class ObsSummary:
    """One observation file read once: what the manifest and the user need to know about it."""

    path: Path
    header: ObsHeader
    epochs: int = 0
    first: GpsTime | None = None
    last: GpsTime | None = None
    interval_s: float | None = None  # the header's INTERVAL, else the median epoch spacing
    satellites_per_epoch: dict[str, float] = field(default_factory=dict)  # system -> mean count
    doppler_share: float = 0.0  # share of pseudoranges with a Doppler on the same signal
    problems: int = 0
    times: tuple[GpsTime, ...] = ()  # every epoch's receiver time tag


def summarise_obs(path: Path) -> ObsSummary:
    """Read a RINEX observation file once with coplane's reader (GPS and BeiDou signals, as every
    method uses); a receiver log with `summarise_log`."""
    problems = Problems(keep=0)
    header, epochs = iter_obs(path, problems)
    summary = summarise(path, header, epochs)
    summary.problems = problems.total  # known once the epochs are read
    return summary


@dataclass
class LogSummary:
    """What one pass over a receiver log (UBX, RTCM 3) found: its observations, or why none could
    be read, and whether it carries broadcast ephemerides (UBX RXM-SFRBX, RTCM 1019/1042)."""

    path: Path
    obs: ObsSummary | None
    error: RecordingError | None
    ephemerides: bool
    readable: bool = True  # False: the file itself could not be read (e.g. a broken archive)

    def unused_reason(self) -> str:
        """Why a log that is neither a receiver nor a navigation source is left out."""
        if self.readable:
            return "a log with neither observations nor ephemerides"
        return f"not read ({str(self.error).removeprefix(f'{self.path}: ')})"


def summarise_log(path: Path) -> LogSummary:
    """A receiver log read once for both things it may hold (`recording.logs`)."""
    problems = Problems(keep=0)
    try:
        log = parse_log(path, problems)
    except RecordingError as exc:
        return LogSummary(path, None, exc, False, readable=False)
    ephemerides = bool(log_navigation(log, problems).ephemerides)
    try:
        header, epochs = log_observations(log)
    except RecordingError as exc:
        return LogSummary(path, None, exc, ephemerides)
    summary = summarise(path, header, epochs)
    summary.problems = problems.total
    return LogSummary(path, summary, None, ephemerides)


def summarise(path: Path, header: ObsHeader, epochs: Iterable[ObsEpoch], problems: int = 0) -> ObsSummary:
    """What a receiver's epochs hold, from epochs already read (a recording's reader has them)."""
    s = ObsSummary(path, header, problems=problems)
    times: list[GpsTime] = []
    sats: dict[str, int] = {sys: 0 for sys in DEFAULT_SYSTEMS}
    ranges = dopplers = 0
    for ep in epochs:
        if ep.flag > 1:  # event records (antenna moved, header lines, splice) carry no epoch
            continue
        times.append(ep.time)
        for o in ep.sats:
            if math.isfinite(o.pseudorange_m):
                sats[o.sat[0]] = sats.get(o.sat[0], 0) + 1
                ranges += 1
                dopplers += math.isfinite(o.doppler_hz)
    s.epochs = len(times)
    s.times = tuple(times)
    if times:
        s.first, s.last = times[0], times[-1]
        s.satellites_per_epoch = {k: n / len(times) for k, n in sats.items() if n}
    s.doppler_share = dopplers / ranges if ranges else 0.0
    spacing = [b - a for a, b in itertools.pairwise(times) if b - a > 1e-3]
    if header.interval_s is not None and header.interval_s > 0:
        s.interval_s = header.interval_s
    elif spacing:
        s.interval_s = round(statistics.median(spacing), 3)
    return s


def vehicle_ids(summaries: Sequence[ObsSummary], others: Sequence[ObsSummary] = ()) -> list[str]:
    """The vehicles' ids: their headers' MARKER NAMEs when every one is a valid id and no two
    receivers share one, the `others` (the base) included (receivers often leave a default such
    as "SEPT"), else every file name's stem made one ([A-Za-z0-9_-], at most 32 characters),
    numbered where two collide."""
    markers = [s.header.marker_name.strip() for s in summaries]
    everyone = markers + [s.header.marker_name.strip() for s in others]
    if all(is_vehicle_id(m) for m in markers) and len(set(everyone)) == len(everyone):
        return markers
    out: list[str] = []
    for s in summaries:
        stem = Path(plain_name(s.path.name)).stem  # "rover.crx.gz": "rover"
        stem = re.sub(r"[^A-Za-z0-9_-]+", "_", stem).strip("_")[:28] or "vehicle"
        vid, n = stem, 2
        while vid in out:
            vid, n = f"{stem}_{n}", n + 1
        out.append(vid)
    return out


def receiver_files(root: Path) -> list[ReceiverFile]:
    """Every RINEX file and receiver log under `root` (sorted; hidden folders and the joined files
    of `SPLICED_DIR` skipped)."""
    if not root.is_dir():
        raise RecordingError(f"{root}: not a directory")
    paths = []
    for p in root.rglob("*"):  # counted as found: a whole disk is refused early, not walked
        if not _looked_in(root, p):
            continue
        if p.is_file():
            paths.append(p)
            if len(paths) > MAX_FILES:
                raise RecordingError(
                    f"{root}: more than {MAX_FILES} files below it; point at one drive's folder"
                )
    return [r for r in (sniff(p) for p in sorted(paths)) if r is not None]


def _looked_in(root: Path, p: Path) -> bool:
    """Hidden folders and the joined files of `SPLICED_DIR` are not the user's files."""
    parts = p.relative_to(root).parts
    return not (any(part.startswith(".") for part in parts) or parts[0] == SPLICED_DIR)


def no_observations(root: Path, found: Sequence[ReceiverFile]) -> str:
    """The error for a folder without any observation file, saying what is there instead: an
    Android GNSS log is named as one (a phone's log is a common first try, and a bare "no
    observation file" beside it reads like a bug), other files by name."""
    known = {r.path for r in found}
    others = sorted(p for p in root.rglob("*") if p.is_file() and p not in known and _looked_in(root, p))
    msg = f"{root}: no observation file (RINEX, UBX or RTCM 3) below it"
    android = next((p for p in others if _android_log(p)), None)
    if android is not None:
        return (
            f"{msg}; {android.relative_to(root)} is an Android GNSS measurement log (GnssLogger, or a "
            "Smartphone Decimeter Challenge device_gnss.csv), which coplane does not read: log RINEX "
            "with GnssLogger, or convert the log to RINEX (e.g. Rokubun's android_rinex)"
        )
    if others:
        names = ", ".join(str(p.relative_to(root)) for p in others[:5])
        more = f" and {len(others) - 5} more" if len(others) > 5 else ""
        return f"{msg}; found {names}{more}: none is RINEX (by its first line), .ubx or .rtcm3"
    return msg


def _android_log(path: Path) -> bool:
    """Whether `path` reads like Android's raw GNSS measurements (GnssLogger's Raw rows, GSDC's
    device_gnss.csv): their header names the raw fields no receiver format has."""
    try:
        with path.open("rb") as f:
            head = f.read(8192).decode("utf-8", "replace")
    except OSError:
        return False
    return "ReceivedSvTimeNanos" in head or "RawPseudorangeMeters" in head


def navigation_files(
    root: Path, found: Sequence[ReceiverFile], logs: Mapping[Path, LogSummary], skipped: list[str]
) -> list[Path]:
    """The navigation files to merge (GPS / BeiDou RINEX first, then the logs with ephemerides: a
    satellite's first record wins); the other files found go to `skipped`."""
    nav = [r.path for r in found if r.kind == "nav" and r.system in NAV_SYSTEMS]
    nav += [p for p, log in logs.items() if log.ephemerides]
    for r in found:
        if r.kind == "nav" and r.system not in NAV_SYSTEMS:
            skipped.append(f"{r.path.relative_to(root)}: {r.system} navigation (coplane uses GPS and BeiDou)")
        elif r.kind == "other":
            why = "cannot be decompressed" if r.system == "unreadable" else "RINEX of another type"
            skipped.append(f"{r.path.relative_to(root)}: {why}")
    if not nav:
        raise RecordingError(
            f"{root}: no GPS or BeiDou navigation file (RINEX, or a UBX / RTCM 3 log with ephemerides) "
            "below it; add one (e.g. the day's BRDC file, or the receiver's own navigation log)"
        )
    return nav
