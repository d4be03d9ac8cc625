"""Option values shared by several commands."""

from __future__ import annotations

import sys
from pathlib import Path

from coplane.errors import ConfigError


def recording_or_default(recording: Path | None) -> Path:
    """The given recording, or the bundled default one (generated into the cache if absent)."""
    if recording is not None:
        return recording
    from coplane.sim.generate import ensure_default_recording

    return ensure_default_recording()


def progress_bars() -> bool:
    """Whether to draw progress bars: on a terminal only. Redrawn into a log file or a pipe, a bar
    leaves one long line of carriage returns in front of the report."""
    return sys.stderr.isatty()


def interruption_rates(text: str) -> list[float]:
    """'0,20,40' (percent) -> [0.0, 0.2, 0.4]."""
    rates = []
    for item in (x.strip() for x in text.split(",")):
        if not item:
            continue
        try:
            rate = float(item)
        except ValueError:
            raise ConfigError(
                f"--interruption {text!r}: {item!r} is not a number (rates in %, e.g. 0,20,40)"
            ) from None
        if not 0.0 <= rate <= 100.0:  # NaN fails too
            raise ConfigError(f"--interruption {text!r}: {item} is not a rate within 0..100 %")
        rates.append(rate / 100.0)
    return rates


def method_names(text: str) -> list[str]:
    """'pc, mci' -> ['pc', 'mci']; the names are checked by the evaluator."""
    return [m.strip() for m in text.split(",") if m.strip()]


def solution_formats(text: str) -> frozenset[str]:
    """'tum,pos' -> {'tum', 'pos'}: the extra solution files `--format` asks for."""
    from coplane.evaluate.solution_files import check_formats

    formats = frozenset(f.strip() for f in text.split(",") if f.strip())
    check_formats(formats)
    return formats


FORMAT_HELP = (
    "Extra solution files, comma-separated: 'tum' (evo) writes solutions/<method>/<vehicle>.tum and"
    " truth/<vehicle>.tum; 'pos' writes RTKLIB's solutions/<method>/<vehicle>.pos (RTKPLOT): Q 4 or 5"
    " where the epoch's own pseudoranges fix it, with or without the base, 7 where motion, ranges or the"
    " plane carry it."
)
