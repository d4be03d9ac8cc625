"""What accuracy is measured against: `--truth` of `coplane eval`, `fleet` and `spp`, and the API's.

Three sources, per vehicle:
- the recording's truth files (the default);
- RTKLIB's carrier-phase RTK against the recording's base (`rtk`: `rtk_reference`), for a drive
  with dual-frequency RINEX and no surveyed trajectory;
- another tool's reference trajectory named for one vehicle (`ID=FILE`): an RTKLIB `.pos` (its
  fixed rows, when it has any), an Inertial Explorer text export (UrbanNav's ground truth) or a
  truth CSV (`recording.trajectories`); or the surveyed point a static receiver stood on
  (`ID=x,y,z` or `ID=lat,lon,h`). A user who has one does not have to write it into the recording
  first (`recording init --truth` takes the same values and does that for good).

A fleet hands whatever it measured against to its API as a directory of truth CSVs
(`save_truth` / `use_truth_files`), so the API does not make it a second time.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from coplane.errors import ConfigError
from coplane.evaluate.rtk_reference import use_rtk_truth
from coplane.gtime import calendar_span
from coplane.recording.csvfiles import read_truth, write_truth
from coplane.recording.positions import parse_truth_value
from coplane.recording.problems import RecordingError
from coplane.recording.reader import Recording
from coplane.recording.trajectories import read_trajectory

# The source for every vehicle: the recording's truth files, or RTKLIB's RTK reference
Truth = Literal["recording", "rtk"]
TRUTHS: tuple[Truth, ...] = ("recording", "rtk")


# a vehicle's reference of its own: a trajectory file, or the ECEF point a static receiver stood on
Reference = Path | tuple[float, float, float]


@dataclass(frozen=True)
class TruthChoice:
    """`source` for every vehicle, then `references` (vehicle -> trajectory file or surveyed
    point) in place of it for the vehicles they name."""

    source: Truth = "recording"
    references: tuple[tuple[str, Reference], ...] = ()


def parse_truth(text: str) -> Truth:
    """`text` (a `--truth` option) as a Truth; ConfigError naming the choices otherwise."""
    for truth in TRUTHS:
        if text == truth:
            return truth
    raise ConfigError(f"--truth must be one of {', '.join(TRUTHS)}, got {text!r}")


def parse_truth_choice(values: Sequence[str] | None) -> TruthChoice:
    """The `--truth` options of `coplane eval` / `coplane fleet`: at most one of the sources'
    names, and any number of ID=FILE or ID=POINT (`recording.positions.parse_truth_value`);
    ConfigError naming the bad value otherwise. Files are only named here; they are read when
    applied to a recording (`apply_truth`)."""
    sources: list[Truth] = []
    refs: dict[str, Reference] = {}
    for value in values or []:
        ident, sep, name = value.partition("=")
        if not sep:
            sources.append(parse_truth(value))
            continue
        if not ident or not name:
            raise ConfigError(f"--truth {value!r}: expected recording, rtk, ID=FILE or ID=x,y,z")
        if ident in refs:
            raise ConfigError(f"--truth: {ident!r} given twice")
        refs[ident] = parse_truth_value(name)
    if len(sources) > 1:
        raise ConfigError(f"--truth: one source for every vehicle, got {', '.join(sources)}")
    return TruthChoice(sources[0] if sources else "recording", tuple(refs.items()))


def apply_truth(rec: Recording, choice: Truth | TruthChoice) -> str:
    """Make `choice` the truth of `rec`'s vehicles; the line that says what it is ("" for the
    recording's own files). ConfigError, with the reason, when a reference cannot be made or read."""
    if not isinstance(choice, TruthChoice):
        choice = TruthChoice(choice)
    notes = [use_rtk_truth(rec)] if choice.source == "rtk" else []
    if choice.references:
        notes.append(use_references(rec, dict(choice.references)))
    return "; ".join(notes)


def use_references(rec: Recording, references: Mapping[str, Reference]) -> str:
    """Replace each named vehicle's truth by its reference: a trajectory file
    (`recording.trajectories`: RTKLIB .pos, Inertial Explorer text, truth CSV) or a surveyed point,
    taken at every epoch the vehicle logged; the line that says what each gave. Bad rows are
    counted in `rec.problems` and skipped; a vehicle the recording lacks, a file that cannot be
    read or one without a usable point is a ConfigError naming it."""
    known = [v.id for v in rec.manifest.vehicles]
    notes = []
    for vid, ref in references.items():
        if vid not in known:
            # a point is not shown: parsed, it is ECEF metres, not what was typed
            where = f"={ref}" if isinstance(ref, Path) else ""
            raise ConfigError(f"--truth {vid}{where}: no such vehicle (vehicles: {', '.join(known)})")
        if not isinstance(ref, Path):  # a static receiver's surveyed point
            epochs = sorted({rec.nominal(e.time) for e in rec.vehicle_epochs(vid)})
            rec.use_truth(vid, dict.fromkeys(epochs, ref))
            notes.append(f"{vid}: a surveyed point at its {len(epochs)} epochs")
            continue
        bad_before, items_before = rec.problems.total, len(rec.problems.items)
        try:
            trajectory = read_trajectory(ref, rec.problems)
        except RecordingError as exc:
            raise ConfigError(f"--truth {vid}={ref}: {exc}") from exc
        bad = rec.problems.total - bad_before
        if not trajectory.points:
            first = rec.problems.items[items_before:][:1]
            detail = f", the first: {first[0]}" if first else ""
            raise ConfigError(f"--truth {vid}={ref}: no usable point ({bad} bad rows{detail})")
        rec.use_truth_points(vid, trajectory.points, ref)
        skipped = f", {bad} bad rows skipped" if bad else ""
        notes.append(f"{vid}: {trajectory.describe()} ({ref.name}{skipped}), {_coverage(rec, vid)}")
    return "references: " + "; ".join(notes)


def _coverage(rec: Recording, vid: str) -> str:
    """How many of the vehicle's epochs the reference gives a truth for, and both spans when it
    is under half: another drive's or day's file would otherwise leave every error blank, and the
    table's empty rows would read like a failed solver."""
    epochs = sorted({rec.nominal(e.time) for e in rec.vehicle_epochs(vid)})
    truth = rec.truth_at(vid)
    matched = sum(1 for t in epochs if t in truth)
    text = f"at {matched} of its {len(epochs)} epochs"
    if epochs and truth and matched < 0.5 * len(epochs):
        times = sorted(truth)
        text += (
            f": the reference is from {calendar_span(times[0], times[-1])}, the observations from "
            f"{calendar_span(epochs[0], epochs[-1])} (GPS time)"
        )
    return text


def missing_truth_note(rec: Recording) -> str:
    """The line that says which vehicles have no truth (no errors for them) and how to get one;
    "" when every vehicle has truth."""
    missing = [v.id for v in rec.manifest.vehicles if not rec.truth(v.id)]
    if not missing:
        return ""
    hint = "; `--truth ID=FILE` measures against a reference trajectory (RTKLIB .pos, Inertial Explorer text)"
    if rec.manifest.base is not None:
        hint += ", `--truth rtk` against RTKLIB's carrier-phase RTK to the base where it holds"
    them = "it" if len(missing) == 1 else "them"
    return f"no truth for {', '.join(missing)}: no errors computed for {them}{hint}"


def save_truth(rec: Recording, directory: Path) -> Path:
    """Every vehicle's truth as `<vehicle>.csv` (the recording format's truth files) in `directory`.

    How `coplane fleet --truth rtk|ID=FILE` hands the API the reference it made or read: RTKLIB's
    two runs per vehicle take longer than the replay's start, so they are made once
    (`use_truth_files`).
    """
    directory.mkdir(parents=True, exist_ok=True)
    for v in rec.manifest.vehicles:
        write_truth(directory / f"{v.id}.csv", rec.truth(v.id))  # with their environment labels
    return directory


def use_truth_files(rec: Recording, directory: Path) -> str:
    """Replace every vehicle's truth by `directory/<vehicle>.csv` where that file exists (`save_truth`);
    the line that says what was used. Bad rows are reported, counted in `rec.problems` and skipped."""
    if not directory.is_dir():
        raise ConfigError(f"truth directory {directory} does not exist")
    used = []
    bad_before = rec.problems.total
    for v in rec.manifest.vehicles:
        path = directory / f"{v.id}.csv"
        if path.is_file():
            points = read_truth(path, rec.problems)
            rec.use_truth(v.id, {p.time: p.ecef_m for p in points}, {p.time: p.environment for p in points})
            used.append(f"{v.id}: {len(points)} epochs")
    if bad := rec.problems.total - bad_before:
        used.append(f"{bad} bad rows skipped")
    return f"truth files in {directory} ({'; '.join(used) or 'none for these vehicles'})"
