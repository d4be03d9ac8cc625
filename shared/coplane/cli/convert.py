"""`coplane convert`: a recording's observations as UBX or RTCM 3 files, with a fleet.toml for them."""

from __future__ import annotations

from enum import StrEnum
from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from coplane.cli.options import recording_or_default
from coplane.cli.render import console


class ReceiverFormat(StrEnum):
    ubx = "ubx"
    rtcm3 = "rtcm3"


def convert(
    recording: Annotated[
        Path | None, typer.Argument(help="Fleet recording; default: the bundled one.")
    ] = None,
    to: Annotated[
        ReceiverFormat, typer.Option("--to", help="ubx (RXM-RAWX) or rtcm3 (MSM7, or --msm, + 1019/1042).")
    ] = (ReceiverFormat.ubx),
    out: Annotated[Path, typer.Option(help="Output recording directory (gets its own fleet.toml).")] = Path(
        "out/convert"
    ),
    msm: Annotated[
        int,
        typer.Option(
            min=4, max=7, help="RTCM 3 MSM level, 4-7 (MSM4 and MSM6 carry no Doppler); --to rtcm3 only."
        ),
    ] = 7,
) -> None:
    """Write each vehicle as UBX or RTCM 3 (the base as RTCM 3), read it back and print the difference."""
    from coplane.recording.convert import convert_recording

    res = convert_recording(recording_or_default(recording), to.value, out, msm)
    console.print(f"resolution: {res.resolution}")
    table = Table(title=f"read back vs source ({to.value})")
    for col in ("receiver", "epochs", "missing sats", "max |dP| mm", "max |dD| Hz", "max |dC/N0| dB-Hz"):
        table.add_column(col, justify="left" if col == "receiver" else "right")
    for d in res.differences:
        table.add_row(
            d.name,
            f"{d.epochs_read}/{d.epochs_source}",
            str(d.satellites_missing),
            f"{d.max_pseudorange_m * 1e3:.3f}",
            f"{d.max_doppler_hz:.2e}",
            f"{d.max_cn0_dbhz:.3f}",
        )
    console.print(table)
    for d in res.differences:
        if d.satellites_missing or d.epochs_read < d.epochs_source:
            console.print(
                f"[yellow]warning:[/yellow] {d.name}: {d.satellites_missing} satellite observation(s) of the "
                f"source, and {d.epochs_source - d.epochs_read} epoch(s), are not in the file read back "
                "at their time: a user of it loses them"
            )
    for s in res.skipped:
        console.print(f"[yellow]not written:[/yellow] {s}")
    console.print(f"wrote {res.out}/fleet.toml ({res.problems} input problem(s) reading it back)")
