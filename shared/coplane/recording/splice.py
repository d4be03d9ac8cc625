"""One receiver's consecutive observation files joined into one (`coplane recording init`).

Reference stations publish hourly files and loggers rotate theirs, while a fleet recording names
one observation file per receiver (docs/recording-format.md). RINEX files are one receiver's when
their headers agree (RINEX version, marker, receiver, antenna, observation types, interval);
receiver logs (UBX, RTCM 3), whose messages name no receiver, when they are of one format with
the same signals and interval. In both cases their epochs must follow one another: no overlap,
and at most `MAX_GAP_S` between one's last epoch and the next one's first. Receivers of one drive
log at the same time, so they never qualify. A joined RINEX file is plain RINEX: the first file's
header without the records that describe one file only (TIME OF LAST OBS, # OF SATELLITES,
PRN / # OF OBS), then every file's epoch records in time order. A joined log is the logs' bytes
one after the other, as the receiver streamed them: a message cut at a file boundary by the
logger's rotation is whole again. Written here because the tools that splice RINEX (gfzrnx, teqc)
are not Python packages this project can depend on, and the job, given the checks above, is a
join of text or bytes.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from pathlib import Path

from coplane.gtime import GpsTime
from coplane.recording.compressed import file_format, open_rinex_text, plain_name, read_log_bytes
from coplane.recording.discover import SPLICED_DIR, ObsSummary

MAX_GAP_S = 60.0  # an hourly file's last epoch to the next one's first is one interval
_ONE_FILE_ONLY = ("TIME OF LAST OBS", "# OF SATELLITES", "PRN / # OF OBS")


def same_receiver(a: ObsSummary, b: ObsSummary) -> bool:
    """Whether two files describe one receiver with the same observations: RINEX headers that
    agree, a marker name required (two anonymous files are not known to be one receiver); logs of
    one format with the same signals and interval (their messages name no receiver)."""
    ha, hb = a.header, b.header
    if file_format(a.path) != "rinex" or file_format(b.path) != "rinex":
        return file_format(a.path) == file_format(b.path) and (ha.obs_types, a.interval_s) == (
            hb.obs_types,
            b.interval_s,
        )
    return bool(ha.marker_name) and (
        ha.version,
        ha.marker_name,
        ha.receiver,
        ha.antenna,
        ha.obs_types,
        a.interval_s,
    ) == (hb.version, hb.marker_name, hb.receiver, hb.antenna, hb.obs_types, b.interval_s)


def _why_same(s: ObsSummary) -> str:
    """What made files one receiver's, for the notes."""
    if file_format(s.path) != "rinex":
        return f"being {file_format(s.path).upper()} logs with the same signals"
    return f"their headers (marker {s.header.marker_name!r})"


def receiver_runs(summaries: Sequence[ObsSummary]) -> list[list[ObsSummary]]:
    """Groups of two or more files that are one receiver's consecutive files, each in time order."""
    runs: list[list[ObsSummary]] = []
    for s in _timed(summaries):
        run = next((r for r in runs if same_receiver(r[-1], s) and _follows(r[-1], s)), None)
        if run is None:
            runs.append([s])
        else:
            run.append(s)
    return [r for r in runs if len(r) > 1]


def _timed(summaries: Sequence[ObsSummary]) -> list[ObsSummary]:
    """The files with epochs, by their first epoch."""
    return sorted((s for s in summaries if s.first is not None and s.last is not None), key=_start)


def _start(s: ObsSummary) -> GpsTime:
    assert s.first is not None
    return s.first


def _follows(a: ObsSummary, b: ObsSummary) -> bool:
    assert a.last is not None and b.first is not None
    return 0.0 < b.first - a.last <= MAX_GAP_S


def spliced_name(first: Path) -> str:
    """`hksc161a.21o` -> `hksc161a-spliced.21o` (compressed names as their plain files)."""
    plain = Path(plain_name(first.name))
    return f"{plain.stem}-spliced{plain.suffix}"


def spliced_summary(run: Sequence[ObsSummary], path: Path) -> ObsSummary:
    """The joined file's summary from its parts' (the same numbers a read of it gives)."""
    epochs = sum(s.epochs for s in run)
    ranges = [s.epochs * sum(s.satellites_per_epoch.values()) for s in run]
    systems = {k for s in run for k in s.satellites_per_epoch}
    return dataclasses.replace(
        run[0],
        path=path,
        epochs=epochs,
        last=run[-1].last,
        satellites_per_epoch={
            k: sum(s.epochs * s.satellites_per_epoch.get(k, 0.0) for s in run) / epochs
            for k in sorted(systems)
        },
        doppler_share=sum(r * s.doppler_share for r, s in zip(ranges, run, strict=True))
        / (sum(ranges) or 1.0),
        problems=sum(s.problems for s in run),
        times=tuple(t for s in run for t in s.times),
    )


def splice(sources: Sequence[Path], out: Path) -> Path:
    """Write `sources` (one receiver's consecutive files, in time order) as one file: plain RINEX,
    or a log's bytes one after the other."""
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".tmp")
    if file_format(out) != "rinex":
        with tmp.open("wb") as b:
            for src in sources:
                b.write(read_log_bytes(src, "receiver log"))
        tmp.replace(out)
        return out
    with tmp.open("w", encoding="latin-1", newline="\n") as f:
        for k, src in enumerate(sources):
            with open_rinex_text(src) as text:
                in_header = True
                for line in text:
                    line = line.rstrip("\r\n")
                    if in_header:
                        if k == 0 and line[60:].strip() not in _ONE_FILE_ONLY:
                            f.write(line + "\n")
                        in_header = line[60:].strip() != "END OF HEADER"
                    else:
                        f.write(line + "\n")
    tmp.replace(out)  # whole or not at all, as the manifest
    return out


def join_runs(
    root: Path,
    summaries: Mapping[Path, ObsSummary],
    roles: Mapping[Path, str],
    notes: list[str],
    only_named: bool = False,
) -> tuple[dict[Path, ObsSummary], dict[Path, tuple[Path, ...]], dict[Path, Path]]:
    """`summaries` with each run of one receiver's consecutive files replaced by the joined file,
    at its first part's place, under `root`/spliced; the joined files and their parts; every
    part's joined file. A run whose parts the user named as different receivers
    (`roles`) is left apart; with `only_named`, so is a run without a file of `roles` (the user named
    the receivers: the others were read only to find their continuations). Each join, or refusal,
    is said in `notes`."""
    splices: dict[Path, tuple[Path, ...]] = {}
    moved: dict[Path, Path] = {}
    for run in receiver_runs(list(summaries.values())):
        parts = tuple(s.path for s in run)
        names = ", ".join(str(p.relative_to(root)) for p in parts)
        named = sorted({roles[p] for p in parts if p in roles})
        if only_named and not named:
            continue
        if len(named) > 1:
            notes.append(
                f"{names}: one receiver's consecutive files by {_why_same(run[0])}, named as "
                f"{' and '.join(named)}: not joined"
            )
            continue
        joined = root / SPLICED_DIR / spliced_name(parts[0])
        n = 2
        while joined in splices:
            joined = joined.with_name(f"{Path(spliced_name(parts[0])).stem}-{n}{joined.suffix}")
            n += 1
        splices[joined] = parts
        moved.update(dict.fromkeys(parts, joined))
        notes.append(
            f"{names}: one receiver's consecutive files by {_why_same(run[0])}, "
            f"joined as {joined.relative_to(root)}"
        )
    notes += _far_apart(list(summaries.values()), root, set(roles) if only_named else None)
    out: dict[Path, ObsSummary] = {}
    for p, s in summaries.items():
        j = moved.get(p)
        if j is None:
            out[p] = s
        elif j not in out:
            out[j] = spliced_summary([summaries[q] for q in splices[j]], j)
    return out, splices, moved


def _far_apart(summaries: Sequence[ObsSummary], root: Path, named: set[Path] | None = None) -> list[str]:
    """Notes on files whose headers say one receiver but whose epochs are more than `MAX_GAP_S`
    apart: kept as separate receivers, which the user may not expect (with `named`, only where
    one of the two is a file the user named)."""
    timed = _timed(summaries)
    out = []
    for k, b in enumerate(timed):
        a = next((a for a in reversed(timed[:k]) if same_receiver(a, b)), None)
        if named is not None and a is not None and not {a.path, b.path} & named:
            continue
        if a is not None and a.last is not None and b.first is not None and b.first - a.last > MAX_GAP_S:
            out.append(
                f"{a.path.relative_to(root)}, {b.path.relative_to(root)}: one receiver by {_why_same(a)}, "
                f"{b.first - a.last:.0f} s apart (more than {MAX_GAP_S:.0f}): not joined, two receivers"
            )
    return out
