"""Counting and reporting bad input without crashing (docs/recording-format.md, input problems).

Every reader takes a `Problems` collector. A problem names the file, the line (1-based, when one
applies) or, in binary files (UBX, RTCM 3), the byte offset, and a short reason; `kind` is a
stable slug for metrics (e.g. "malformed-line").
"""

from __future__ import annotations

import logging
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

from coplane.errors import CoplaneError

log = logging.getLogger("coplane.recording")


@dataclass(frozen=True, slots=True)
class Problem:
    path: str
    line: int | None
    kind: str
    reason: str
    offset: int | None = None  # byte offset in a binary file (UBX, RTCM 3)

    def __str__(self) -> str:
        where = f"{self.path}:{self.line}" if self.line is not None else self.path
        if self.offset is not None:
            where = f"{self.path}:byte {self.offset}"
        return f"{where}: {self.reason} [{self.kind}]"


@dataclass
class Problems:
    """Collects problems; keeps the first `keep` in full and counts all of them by kind and by file."""

    keep: int = 1000
    items: list[Problem] = field(default_factory=list)
    counts: Counter[str] = field(default_factory=Counter)
    by_path: Counter[str] = field(default_factory=Counter)

    def add(
        self, path: str | Path, line: int | None, kind: str, reason: str, *, offset: int | None = None
    ) -> None:
        p = Problem(str(path), line, kind, reason, offset)
        self.counts[kind] += 1
        self.by_path[p.path] += 1
        if len(self.items) < self.keep:
            self.items.append(p)
            log.warning("%s", p)

    @property
    def total(self) -> int:
        return sum(self.counts.values())

    def __bool__(self) -> bool:
        return self.total > 0

    def __len__(self) -> int:
        return self.total


class RecordingError(CoplaneError):
    """A recording cannot be used at all (missing manifest key, unknown format, bad path, ...)."""
