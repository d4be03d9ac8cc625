"""Option values shared by several commands."""

from __future__ import annotations

from pathlib import Path


def recording_or_default(recording: Path | None) -> Path:
    """The given recording, or the bundled default one (generated into the cache if absent)."""
    if recording is not None:
        return recording
    from coplane.sim.generate import ensure_default_recording

    return ensure_default_recording()
