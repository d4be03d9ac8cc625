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
    try:
        rates = [float(x) / 100.0 for x in text.split(",") if x.strip()]
    except ValueError as exc:  # float()'s own message names the bad item
        raise ConfigError(str(exc)) from exc
    if any(not 0.0 <= r <= 1.0 for r in rates):
        raise ConfigError("interruption rates must be within 0..100 %")
    return rates


def method_names(text: str) -> list[str]:
    """'pc, mci' -> ['pc', 'mci']; the names are checked by the evaluator."""
    return [m.strip() for m in text.split(",") if m.strip()]
