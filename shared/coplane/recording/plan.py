"""A fleet recording for files a user already has: the manifest (fleet.toml) of a drive's folder.

A test fleet logs RINEX (a receiver's own files, RTKLIB's `convbin`, a CORS download) or UBX / RTCM 3
logs; coplane reads recordings described by a manifest (../spec/fleet-recording.md).
`plan_recording` looks at the files of a folder (`recording.discover`), reads every observation
file once and returns the manifest that describes them, with notes on everything it chose;
`write_plan` writes it (`coplane recording init`). Nothing that changes results is guessed: which
file is the base and where its antenna is are the user's to say (a RINEX header's APPROX POSITION
XYZ is often the receiver's own fix, metres off, and DGNSS carries any base error into every
vehicle).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from coplane.errors import ConfigError
from coplane.gtime import calendar_span
from coplane.ids import is_vehicle_id
from coplane.recording.csvfiles import write_truth
from coplane.recording.discover import (
    LogSummary,
    ObsSummary,
    navigation_files,
    no_observations,
    receiver_files,
    summarise_log,
    summarise_obs,
    vehicle_ids,
)
from coplane.recording.manifest import MANIFEST_NAME, write_manifest
from coplane.recording.model import BaseSpec, Manifest, TruthPoint, UwbSpec, VehicleSpec
from coplane.recording.positions import header_antenna_position
from coplane.recording.problems import Problems, RecordingError
from coplane.recording.splice import join_runs, splice
from coplane.recording.trajectories import read_trajectory, sniff

DEFAULT_ANTENNA_HEIGHT_M = 1.5  # a car's roof, when the user does not say


@dataclass
class RecordingPlan:
    """The manifest `plan_recording` chose, every observation file it read, and why it chose so."""

    manifest: Manifest
    summaries: dict[Path, ObsSummary]
    roles: dict[Path, str]  # observation file -> vehicle id, or "base"
    skipped: list[str]  # files found and not used, each with the reason
    notes: list[str]
    # truth files to write: a surveyed point (`--truth ID=x,y,z`), or a trajectory converted from
    # another tool's file (`--truth ID=FILE.pos`)
    truth_to_write: dict[str, list[TruthPoint]] = field(default_factory=dict)
    # joined files to write (`recording.splice`): the joined file -> its parts, in time order
    splices: dict[Path, tuple[Path, ...]] = field(default_factory=dict)


def inside(root: Path, path: Path, what: str) -> Path:
    """`path` (as given, else relative to `root`) resolved, and inside `root` as the format requires."""
    found = _given_file(root, path, what)
    if not found.is_relative_to(root.resolve()):
        raise ConfigError(
            f"{what} {found}: outside {root}; a recording's files must be inside its directory (move or copy it there)"
        )
    return found


def plan_recording(
    root: Path,
    *,
    base: Path | None = None,
    base_position: tuple[float, float, float] | Literal["header"] | None = None,
    vehicles: Mapping[str, Path] | None = None,
    antenna_height_m: float | None = None,
    interval_s: float | None = None,
    name: str | None = None,
    uwb: Path | None = None,
    truth: Mapping[str, Path | tuple[float, float, float]] | None = None,
) -> RecordingPlan:
    """The manifest of the files under `root`: every observation file (RINEX, or a .ubx / .rtcm3
    log with observations) is a vehicle (or only `vehicles`, id -> file) but `base`; every GPS /
    BeiDou navigation file (RINEX, or a log with ephemerides) is merged; `truth/<id>.csv` and
    `uwb.csv` are taken where the format puts them. `truth`:
    a vehicle's reference trajectory file, or the ECEF point where it stood (a static test)."""
    root = root.resolve()
    found = receiver_files(root)
    notes: list[str] = []
    skipped: list[str] = []
    logs = {
        r.path.resolve(): summarise_log(r.path.resolve()) for r in found if r.kind == "log"
    }  # each read once
    if not any(r.kind in ("obs", "log") for r in found):  # before the navigation: say what is there
        raise RecordingError(no_observations(root, found))
    nav = navigation_files(root, found, logs, skipped)
    base_path = inside(root, base, "--base") if base is not None else None
    if (base_path is None) != (base_position is None):
        raise ConfigError(
            "--base needs --base-position (its surveyed antenna position, or 'header')"
            if base_path is not None
            else "--base-position without --base: which file is the base station?"
        )
    every = [r.path.resolve() for r in found if r.kind == "obs"] + list(logs)
    if vehicles:
        chosen = {vid: inside(root, p, f"--vehicle {vid}") for vid, p in vehicles.items()}
        bad = [vid for vid in chosen if not is_vehicle_id(vid)]
        if bad:
            raise ConfigError(f"--vehicle: invalid id {bad[0]!r} (allowed: [A-Za-z0-9_-]{{1,32}})")
        files = list(chosen.values())
        twice = next((p for p in files if files.count(p) > 1 or p == base_path), None)
        if twice is not None:
            raise ConfigError(
                f"--vehicle: {twice.name} is named twice (or is the base): one file per receiver"
            )
        # the other files too, read only to find the named ones' continuations (a base's next hour)
        candidates = files + [p for p in every if p not in files]
    else:
        chosen = {}
        candidates = every
    if base_path is not None and base_path not in candidates:
        candidates.append(base_path)
    # a file found (not named by the user) that cannot be read is skipped with its reason; a log
    # is a vehicle only when it holds observations (one may hold navigation only)
    named = set(chosen.values()) | {base_path}
    summaries, unreadable = _summaries(candidates, {p for p in candidates if p not in named}, logs)
    skipped += [f"{p.relative_to(root)}: {why}" for p, why in unreadable.items()]
    unused = [p for p in candidates if p not in summaries and p not in unreadable and p not in nav]
    skipped += [f"{p.relative_to(root)}: {logs[p].unused_reason()}" for p in unused]  # only logs are left
    # one receiver's consecutive files (a CORS's hourly files, a logger's rotated logs) become one
    roles_given = {p: vid for vid, p in chosen.items()} | ({base_path: "base"} if base_path else {})
    summaries, splices, moved = join_runs(root, summaries, roles_given, notes, only_named=bool(chosen))
    nav = list(dict.fromkeys(moved.get(p, p) for p in nav))  # a joined log's ephemerides: from it
    base_path = moved.get(base_path, base_path) if base_path is not None else None
    chosen = {vid: moved.get(p, p) for vid, p in chosen.items()}
    if chosen:  # the files read only for continuations are not receivers of the recording
        kept = {*chosen.values(), base_path}
        skipped += [f"{p.relative_to(root)}: not named with --vehicle" for p in summaries if p not in kept]
        summaries = {p: s for p, s in summaries.items() if p in kept}
    rovers = [p for p in summaries if p != base_path]
    if not rovers:
        raise RecordingError(f"{root}: no observation file (RINEX, UBX or RTCM 3) for a vehicle below it")
    if not chosen:
        base_summary = [summaries[base_path]] if base_path is not None else []
        chosen = dict(zip(vehicle_ids([summaries[p] for p in rovers], base_summary), rovers, strict=True))
    roles = {p: vid for vid, p in chosen.items()} | ({base_path: "base"} if base_path else {})
    empty = [p for p, s in summaries.items() if s.epochs == 0]
    if empty:
        raise RecordingError(f"{empty[0]}: no epoch with GPS or BeiDou pseudoranges")
    interval = (
        interval_s if interval_s is not None else _fleet_interval([summaries[p] for p in chosen.values()])
    )
    if interval <= 0 or not math.isfinite(interval):
        raise ConfigError(f"--interval {interval}: must be a positive number of seconds")
    notes += coverage_notes(summaries, chosen, base_path, interval)
    base_spec = None
    if base_path is not None and base_position is not None:
        base_spec = BaseSpec(base_path, _base_position(base_position, summaries[base_path], notes))
    truths, static = _truths(root, chosen, summaries, truth or {}, interval, notes)
    if uwb is None and (root / "uwb.csv").is_file():
        uwb = root / "uwb.csv"
        notes.append("uwb.csv taken as the inter-vehicle ranges")
    if antenna_height_m is None:
        antenna_height_m = DEFAULT_ANTENNA_HEIGHT_M
        notes.append(
            f"every vehicle's antenna taken {antenna_height_m:g} m above the road (--antenna-height, or "
            "antenna_height_m in fleet.toml per vehicle): the plane methods put the road that far below it"
        )
    specs = tuple(VehicleSpec(vid, p, antenna_height_m, truths.get(vid)) for vid, p in chosen.items())
    uwb_spec = UwbSpec(inside(root, uwb, "--uwb")) if uwb is not None else None
    manifest = Manifest(root, name or root.name, interval, tuple(nav), specs, base_spec, uwb_spec)
    return RecordingPlan(manifest, summaries, roles, skipped, notes, static, splices)


def _summaries(
    paths: Sequence[Path], optional: set[Path], logs: Mapping[Path, LogSummary]
) -> tuple[dict[Path, ObsSummary], dict[Path, str]]:
    """Each file read once. An `optional` one (found, not named by the user) that cannot be read
    is left out with the reason (the second dict; a log's reason is only that it holds no
    observations, as a navigation log does), and so is an optional log without observations."""
    out: dict[Path, ObsSummary] = {}
    unreadable: dict[Path, str] = {}
    for p in paths:
        try:
            summary = _read_summary(p, logs)
        except RecordingError as exc:
            if p not in optional:
                raise
            if p not in logs:
                unreadable[p] = f"not read ({str(exc).removeprefix(f'{p}: ')})"
            continue
        if summary.epochs or p not in optional:
            out[p] = summary
        elif p not in logs:
            unreadable[p] = "no epoch with GPS or BeiDou pseudoranges"
    return out, unreadable


def _read_summary(path: Path, logs: Mapping[Path, LogSummary]) -> ObsSummary:
    """A RINEX file's summary, or a log's from its one read (its error raised again)."""
    log = logs.get(path)
    if log is None:
        return summarise_obs(path)
    if log.obs is None:
        raise log.error or RecordingError(f"{path}: no observations")
    return log.obs


def _base_position(
    given: tuple[float, float, float] | Literal["header"], base: ObsSummary, notes: list[str]
) -> tuple[float, float, float]:
    """The base antenna's ECEF position: as given, or its header's (said in `notes`)."""
    if given != "header":
        return given
    notes.append(
        f"base position from {base.path.name}'s header (APPROX POSITION XYZ + antenna delta): "
        "DGNSS moves every vehicle by any error in it; give the surveyed one if it is known"
    )
    return header_antenna_position(base.header, base.path)


def _truths(
    root: Path,
    vehicles: Mapping[str, Path],
    summaries: Mapping[Path, ObsSummary],
    given: Mapping[str, Path | tuple[float, float, float]],
    interval: float,
    notes: list[str],
) -> tuple[dict[str, Path], dict[str, list[TruthPoint]]]:
    """Each vehicle's truth file: given; converted from another tool's trajectory (RTKLIB .pos,
    Inertial Explorer text: `recording.trajectories`) or a surveyed point, either written as
    truth/<id>.csv (one row per epoch it logged for a point); or truth/<id>.csv where the format
    puts it."""
    unknown = sorted(set(given) - set(vehicles))
    if unknown:
        raise ConfigError(f"--truth {unknown[0]}: no such vehicle (vehicles: {', '.join(vehicles)})")
    files: dict[str, Path] = {}
    written: dict[str, list[TruthPoint]] = {}
    for vid, obs in vehicles.items():
        value = given.get(vid)
        default = root / "truth" / f"{vid}.csv"
        if isinstance(value, Path):
            path = _given_file(root, value, f"--truth {vid}")
            if sniff(path) == "csv":
                files[vid] = inside(root, path, f"--truth {vid}")
                continue
            problems = Problems()
            trajectory = read_trajectory(path, problems)
            bad = f"{problems.total} bad rows, the first: {problems.items[0]}" if problems.items else ""
            if not trajectory.points:
                raise ConfigError(f"--truth {vid} {path}: no usable point ({bad or 'no rows'})")
            files[vid], written[vid] = default, trajectory.points
            bad = f"; {bad} (skipped)" if bad else ""
            notes.append(f"{vid}: truth/{vid}.csv converted from {path.name}: {trajectory.describe()}{bad}")
            notes += _truth_coverage(vid, trajectory.points, summaries[obs], interval)
        elif value is not None:  # a surveyed point: the vehicle stood there at every epoch it logged
            files[vid] = default
            epochs = sorted({t.round_to(interval) for t in summaries[obs].times})
            written[vid] = [TruthPoint(t, value) for t in epochs]
        elif default.is_file():  # the format's own layout, e.g. a `coplane convert` or simulator folder
            files[vid] = default
            notes.append(f"{vid}: truth/{vid}.csv taken as its reference trajectory")
    return files, written


def _given_file(root: Path, path: Path, what: str) -> Path:
    """A file the user named, as given or relative to `root`; ConfigError if there is none."""
    candidates = [path] if path.is_absolute() else [root / path, path]
    found = next((c.resolve() for c in candidates if c.is_file()), None)
    if found is None:
        raise ConfigError(f"{what} {path}: no such file (in {root} or the current directory)")
    return found


def _fleet_interval(vehicles: Sequence[ObsSummary]) -> float:
    """The vehicles' common epoch spacing; receivers logging at different rates need --interval."""
    rates = {s.path.name: s.interval_s for s in vehicles}
    known = {round(v, 3) for v in rates.values() if v is not None}
    if not known:
        raise ConfigError("no observation file states or shows its epoch interval; give --interval")
    if len(known) > 1:
        listed = ", ".join(f"{n} {v} s" for n, v in rates.items())
        raise ConfigError(
            f"the vehicles log at different intervals ({listed}); give --interval: the slowest,"
            f" --interval {max(known):g}, decimates the faster ones (each keeps its epoch nearest every"
            f" {max(known):g} s), a shorter one leaves the slower ones gaps"
        )
    return known.pop()


def _truth_coverage(vid: str, points: Sequence[TruthPoint], obs: ObsSummary, interval: float) -> list[str]:
    """A note when a reference trajectory misses most of the vehicle's epochs (another drive's
    file, another day's): errors would be computed on few epochs, or none, without a word."""
    epochs = {t.round_to(interval) for t in obs.times}
    covered = len(epochs & {p.time.round_to(interval) for p in points})
    if not epochs or covered >= 0.5 * len(epochs):
        return []
    times = sorted(p.time for p in points)
    return [
        f"{vid}: its truth covers {covered} of its {len(epochs)} epochs: the trajectory is from "
        f"{calendar_span(times[0], times[-1])}, the observations from {calendar_span(min(epochs), max(epochs))} "
        "(GPS time)"
    ]


def coverage_notes(
    summaries: Mapping[Path, ObsSummary], vehicles: Mapping[str, Path], base: Path | None, interval: float
) -> list[str]:
    """What the user should know before running: a base at another rate or time, no Doppler."""
    notes = []
    for vid, p in vehicles.items():
        s = summaries[p]
        if s.doppler_share < 0.5:
            notes.append(
                f"{vid}: Doppler on {100 * s.doppler_share:.0f} % of its pseudoranges: velocities "
                "come from the motion model where it is missing (docs/fgo.md)"
            )
    if base is not None:
        b = summaries[base]
        # a slower base leaves epochs without corrections; a faster one is decimated (reader.py)
        if b.interval_s is not None and b.interval_s > interval + 1e-3:
            notes.append(
                f"base logs every {b.interval_s:g} s, the vehicles every {interval:g} s: DGNSS corrections "
                "exist only at the base's epochs"
            )
        firsts = [summaries[p].first for p in vehicles.values()]
        lasts = [summaries[p].last for p in vehicles.values()]
        if b.first is not None and b.last is not None and firsts and lasts:
            start = min(t for t in firsts if t is not None)
            end = max(t for t in lasts if t is not None)
            if b.last < start or b.first > end:
                notes.append("the base's observations do not overlap the vehicles' in time: no DGNSS")
    return notes


def write_plan(plan: RecordingPlan, force: bool = False) -> Path:
    """Write the plan's truth files (surveyed points, converted trajectories), its joined files and
    its fleet.toml; an existing file is replaced only with `force` (ConfigError naming it
    otherwise). Returns the manifest's path."""
    root = plan.manifest.root
    targets = [root / "truth" / f"{vid}.csv" for vid in plan.truth_to_write] + [
        *plan.splices,
        root / MANIFEST_NAME,
    ]
    existing = [p for p in targets if p.exists()]
    if existing and not force:
        raise ConfigError(f"{existing[-1]} exists; --force replaces it")
    for vid, points in plan.truth_to_write.items():
        write_truth(root / "truth" / f"{vid}.csv", points)
    for joined, parts in plan.splices.items():
        splice(parts, joined)
    return write_manifest(plan.manifest)
