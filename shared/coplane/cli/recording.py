"""`coplane recording init | show`: a fleet recording (fleet.toml) for a folder of receiver files
(RINEX, compressed or not, UBX and RTCM 3 logs), and what a recording holds."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.table import Table

from coplane.cli.render import console, err_console
from coplane.errors import ConfigError

if TYPE_CHECKING:  # the command imports its library lazily, as every command does
    from coplane.gtime import GpsTime
    from coplane.recording.discover import ObsSummary

COLUMNS = (
    "role",
    "file",
    "format",
    "epochs",
    "span s",
    "interval s",
    "G / C per epoch",
    "Doppler %",
    "problems",
)

recording_app = typer.Typer(
    name="recording",
    help="Fleet recordings: describe a folder of receiver files as one (fleet.toml), show what one holds.",
    no_args_is_help=True,
)


def _pairs(values: list[str] | None, option: str) -> dict[str, str]:
    """`ID=VALUE` options as {id: value}; ConfigError naming the option otherwise."""
    out: dict[str, str] = {}
    for v in values or []:
        ident, sep, value = v.partition("=")
        if not sep or not ident or not value:
            raise ConfigError(f"{option} {v!r}: expected ID=VALUE")
        if ident in out:
            raise ConfigError(f"{option}: {ident!r} given twice")
        out[ident] = value
    return out


@recording_app.command("init")
def init(
    directory: Annotated[
        Path, typer.Argument(help="The folder holding the receiver files (searched recursively).")
    ],
    base: Annotated[
        Path | None, typer.Option(help="The reference station's observation file (enables DGNSS).")
    ] = None,
    base_position: Annotated[
        str | None,
        typer.Option(
            help="The base antenna: ECEF 'x,y,z' (m), 'lat,lon,h' (deg, deg, ellipsoidal m), or 'header' "
            "for its RINEX header's APPROX POSITION XYZ (often metres off)."
        ),
    ] = None,
    vehicle: Annotated[
        list[str] | None,
        typer.Option(
            help="ID=FILE (repeatable): only these files are vehicles, with these ids; default: "
            "every other observation file, named by its MARKER NAME or file name."
        ),
    ] = None,
    antenna_height: Annotated[
        float | None,
        typer.Option(
            min=0.0,
            help="Every vehicle's antenna height above the road (m), for the plane methods; "
            "default 1.5 m, said when used.",
        ),
    ] = None,
    interval: Annotated[
        float | None, typer.Option(help="Epoch spacing (s); default: the files' own.")
    ] = None,
    name: Annotated[str | None, typer.Option(help="The recording's name; default: the folder's.")] = None,
    uwb: Annotated[
        Path | None, typer.Option(help="Inter-vehicle ranges (uwb.csv, docs/recording-format.md).")
    ] = None,
    truth: Annotated[
        list[str] | None,
        typer.Option(
            help="ID=FILE (repeatable): a vehicle's reference trajectory: a truth CSV inside DIRECTORY, or "
            "an RTKLIB .pos (fixed rows only, if it has any) or Inertial Explorer text export, converted to "
            "truth/ID.csv; ID=x,y,z or ID=lat,lon,h: the surveyed point a static receiver stood on "
            "(written as truth/ID.csv)."
        ),
    ] = None,
    dry_run: Annotated[bool, typer.Option(help="Print fleet.toml instead of writing it.")] = False,
    force: Annotated[bool, typer.Option(help="Replace an existing fleet.toml.")] = False,
) -> None:
    """Describe the RINEX files of DIRECTORY as a fleet recording: writes DIRECTORY/fleet.toml.

    Every observation file becomes a vehicle but the --base; every GPS and BeiDou navigation file
    is merged. Each observation file is read once, and what was found is printed, so the choice
    can be checked before `coplane spp` or `coplane eval` run on it.
    """
    import tomli_w

    from coplane.recording.health import ephemeris_gap
    from coplane.recording.manifest import MANIFEST_NAME, manifest_dict
    from coplane.recording.plan import plan_recording, write_plan
    from coplane.recording.positions import parse_position, parse_truth_value
    from coplane.recording.reader import open_recording

    target = directory / MANIFEST_NAME
    if target.exists() and not (force or dry_run):
        raise ConfigError(f"{target} exists; --force replaces it")
    plan = plan_recording(
        directory,
        base=base,
        base_position=parse_position(base_position) if base_position is not None else None,
        vehicles={k: Path(v) for k, v in _pairs(vehicle, "--vehicle").items()},
        antenna_height_m=antenna_height,
        interval_s=interval,
        name=name,
        uwb=uwb,
        truth={k: parse_truth_value(v) for k, v in _pairs(truth, "--truth").items()},
    )
    root = plan.manifest.root
    print_receivers(f"observation files in {root}", root, plan.summaries, plan.roles)
    console.print("navigation: " + ", ".join(str(p.relative_to(root)) for p in plan.manifest.nav_files))
    for line in plan.skipped:
        console.print(f"not used: {line}")
    if dry_run:
        for note in plan.notes:
            err_console.print(f"note: {note}")
        typer.echo(tomli_w.dumps(manifest_dict(plan.manifest)))
        return
    path = write_plan(plan, force)
    # the observations' span is known from the plan's one read of each file: only the navigation
    # files are read again, as the recording reads them
    vehicles = [plan.summaries[v.obs] for v in plan.manifest.vehicles]
    gap = ephemeris_gap(
        open_recording(path),
        min(s.first for s in vehicles if s.first is not None),
        max(s.last for s in vehicles if s.last is not None),
    )
    for note in [*plan.notes, *([gap + ": nothing can be positioned"] if gap else [])]:
        err_console.print(f"note: {note}")
    console.print(
        f"wrote {path} ({len(plan.manifest.vehicles)} vehicle(s), "
        f"{'a base' if plan.manifest.base else 'no base'}, interval {plan.manifest.interval_s:g} s); "
        f"next: coplane recording show {directory}, coplane spp {directory} --out out/spp.pos, "
        f"coplane eval {directory} --out out/eval"
    )


@recording_app.command("show")
def show(
    recording: Annotated[Path, typer.Argument(help="Fleet recording directory (with fleet.toml).")],
) -> None:
    """What a recording holds, before anything is solved: per receiver its epochs, interval,
    satellites and Doppler; the ephemerides per system; truth and ranges; the input problems."""
    import numpy as np

    from coplane.geo import ecef_to_geodetic
    from coplane.gnss.epoch_solver import first_fix
    from coplane.recording.discover import summarise
    from coplane.recording.health import ephemeris_days, input_health
    from coplane.recording.plan import coverage_notes
    from coplane.recording.reader import open_recording

    rec = open_recording(recording)
    m = rec.manifest
    roles = {v.obs: v.id for v in m.vehicles} | ({m.base.obs: "base"} if m.base else {})
    # from the epochs the recording's reader keeps (read once, for every figure below)
    headers = {v.obs: rec.vehicle_header(v.id) for v in m.vehicles}
    epochs = {v.obs: rec.vehicle_epochs(v.id) for v in m.vehicles}
    base_header = rec.base_header()
    if m.base is not None and base_header is not None:
        headers[m.base.obs], epochs[m.base.obs] = base_header, rec.base_epochs()
    summaries = {p: summarise(p, headers[p], epochs[p], rec.problems.by_path[str(p)]) for p in roles}
    print_receivers(f"{m.name} ({m.root})", m.root, summaries, roles)
    systems: dict[str, list[GpsTime]] = {}
    for sat, ephs in rec.nav.ephemerides.items():
        systems.setdefault(sat[0], []).extend(e.toe for e in ephs)
    nav = ", ".join(
        f"{sys} {len({s for s in rec.nav.ephemerides if s[0] == sys})} satellites ({len(toes)} ephemerides "
        f"from {ephemeris_days(toes)}, toe {min(toes)} .. {max(toes)})"
        for sys, toes in sorted(systems.items())
    )
    console.print(f"navigation: {nav}; ionosphere: {', '.join(sorted(rec.nav.iono)) or 'none'}")
    if m.base is not None:
        lat, lon, h = ecef_to_geodetic(np.array(m.base.position_ecef_m))
        console.print(
            f"base: {m.base.obs.relative_to(m.root)} at {np.degrees(lat):.7f}, {np.degrees(lon):.7f}, {h:.3f} m"
        )
        for v in m.vehicles:  # DGNSS weakens with distance: the atmosphere decorrelates
            fix = first_fix(epochs[v.obs], rec.nav)
            far = (
                "-"
                if fix is None
                else f"{np.linalg.norm(fix - np.array(m.base.position_ecef_m)) / 1e3:.1f} km"
            )
            console.print(f"{v.id}: {far} from the base at its first SPP fix")
    for v in m.vehicles:
        truth = rec.truth_at(v.id)
        nominal = {rec.nominal(ep.time) for ep in epochs[v.obs]}
        covered = len(nominal & set(truth)) / len(nominal) if nominal else 0.0
        console.print(
            f"{v.id}: antenna {v.antenna_height_m:g} m above the road; truth "
            + (f"{len(truth)} rows, {100 * covered:.0f} % of its epochs" if truth else "none")
        )
    ranges = rec.uwb()
    if m.uwb is not None:
        pairs = {r.pair for r in ranges}
        console.print(f"ranges: {len(ranges)} between {len(pairs)} pair(s), sigma {m.uwb.sigma_m:g} m")
    vehicles = {v.id: v.obs for v in m.vehicles}
    notes = coverage_notes(summaries, vehicles, m.base.obs if m.base else None, m.interval_s)
    health = input_health(rec)
    if health.nav_gap:
        notes.append(health.nav_gap + ": nothing can be positioned")
    for path, (skipped, own) in rec.decimations().items():
        notes.append(
            f"{roles[path]}: logs every {own:.3g} s, decimated to the recording's {m.interval_s:g} s"
            f" ({skipped} epochs between its epochs skipped, not counted as problems)"
        )
    for note in notes:
        err_console.print(f"note: {note}")
    console.print(
        f"{health.records} records kept, {health.problems} input problem(s)"
        + (f": {dict(rec.problems.counts)}" if health.problems else "")
    )


def print_receivers(
    title: str, root: Path, summaries: Mapping[Path, ObsSummary], roles: Mapping[Path, str]
) -> None:
    """One row per observation file: what it is for, what it holds."""
    from coplane.recording.compressed import file_format

    table = Table(title=title)
    for col in COLUMNS:
        table.add_column(col, justify="left" if col in ("role", "file", "format") else "right")
    for path, s in summaries.items():
        span = (s.last - s.first) if s.first is not None and s.last is not None else 0.0
        per = " / ".join(f"{s.satellites_per_epoch.get(k, 0.0):.1f}" for k in ("G", "C"))
        log = {"ubx": "UBX", "rtcm3": "RTCM 3"}.get(file_format(path))
        table.add_row(
            roles.get(path, "-"),
            str(path.relative_to(root)),
            log or f"RINEX {s.header.version:.2f}",
            str(s.epochs),
            f"{span:.0f}",
            "-" if s.interval_s is None else f"{s.interval_s:g}",
            per,
            f"{100 * s.doppler_share:.0f}",
            str(s.problems),
        )
    console.print(table)
