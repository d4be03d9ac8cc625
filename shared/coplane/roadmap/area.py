"""Boxes of tiles, and which tiles changed when: what a fusion server needs to answer an agent's
"the tiles around me, and what changed since my last answer" (docs/roadmap.md, "Tiles on the bus").

A box is a range of rows and a range of columns of the grid (`coplane.roadmap.grid`). Columns are
numbered per row, but within a few kilometres their widths agree to 1e-6, so a box of rows and
columns around a vehicle's tile is the square around it. `RevisionIndex` stamps each tile with the
revision at which it last changed (one revision per commit or batch taken) and files tiles by
blocks of BLOCK_TILES x BLOCK_TILES, so a box costs the blocks it meets, not a scan of the map.
"""

from __future__ import annotations

import re
from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass

from coplane.roadmap.grid import TileKey

BLOCK_TILES = 64  # 1.3 km with 20 m tiles: a vehicle's box meets a few blocks
_BOX = re.compile(r"^(-?\d{1,9}),(-?\d{1,9}),(-?\d{1,9}),(-?\d{1,9})$")


@dataclass(frozen=True)
class TileBox:
    """Tiles with row0 <= row <= row1 and col0 <= col <= col1; text form "row0,row1,col0,col1"."""

    row0: int
    row1: int
    col0: int
    col1: int

    def __post_init__(self) -> None:
        if self.row0 > self.row1 or self.col0 > self.col1:
            raise ValueError(f"not a box of tiles (row0 <= row1, col0 <= col1): {self}")

    def __str__(self) -> str:
        return f"{self.row0},{self.row1},{self.col0},{self.col1}"

    @classmethod
    def parse(cls, text: str) -> TileBox:
        """The inverse of `str`; ValueError naming the text otherwise."""
        m = _BOX.match(text) if isinstance(text, str) else None
        if m is None:
            raise ValueError(f"not a box of tiles (row0,row1,col0,col1): {str(text)[:60]!r}")
        return cls(*(int(g) for g in m.groups()))

    @classmethod
    def around(cls, key: TileKey, radius_tiles: int) -> TileBox:
        """The square of tiles within `radius_tiles` rows and columns of `key`."""
        r = max(0, int(radius_tiles))
        return cls(key.row - r, key.row + r, key.col - r, key.col + r)

    def __contains__(self, key: object) -> bool:
        return (
            isinstance(key, TileKey)
            and self.row0 <= key.row <= self.row1
            and self.col0 <= key.col <= self.col1
        )

    def keeps(self, key: TileKey, margin: int) -> bool:
        """Whether `key` is at least `margin` tiles inside the box: a vehicle there still has
        `margin` tiles of map ahead whichever way it drives."""
        return (
            self.row0 + margin <= key.row <= self.row1 - margin
            and self.col0 + margin <= key.col <= self.col1 - margin
        )

    def covers(self, other: TileBox) -> bool:
        """Whether every tile of `other` is in this box."""
        return (
            self.row0 <= other.row0
            and other.row1 <= self.row1
            and self.col0 <= other.col0
            and other.col1 <= self.col1
        )

    def meets(self, other: TileBox) -> bool:
        return not (
            other.row1 < self.row0
            or other.row0 > self.row1
            or other.col1 < self.col0
            or other.col0 > self.col1
        )

    def intersection(self, other: TileBox) -> TileBox | None:
        """The tiles in both boxes, None if none."""
        if not self.meets(other):
            return None
        return TileBox(
            max(self.row0, other.row0),
            min(self.row1, other.row1),
            max(self.col0, other.col0),
            min(self.col1, other.col1),
        )


class RevisionIndex:
    """Each tile's revision (when it last changed), its block, and the recent revisions' tiles,
    for `changed` queries. An agent's refresh (the same box, a revision a few commits old) costs
    the tiles changed since, not a scan of its box: the last revisions' tiles are kept, up to
    `log_tiles` of them (older ones are answered by scanning the box's blocks)."""

    def __init__(self, log_tiles: int = 200_000) -> None:
        self.revision = 0
        self._rev: dict[TileKey, int] = {}
        self._blocks: dict[tuple[int, int], set[TileKey]] = {}
        self._log: deque[tuple[int, tuple[TileKey, ...]]] = deque()  # (revision, its tiles)
        self._log_tiles, self._logged = log_tiles, 0

    def touch(self, keys: Iterable[TileKey]) -> int:
        """One new revision for these tiles (a commit, a batch from a peer); the revision."""
        self.revision += 1
        touched = tuple(keys)
        for k in touched:
            self._rev[k] = self.revision
            self._blocks.setdefault((k.row // BLOCK_TILES, k.col // BLOCK_TILES), set()).add(k)
        self._log.append((self.revision, touched))
        self._logged += len(touched)
        while len(self._log) > 1 and self._logged > self._log_tiles:
            self._logged -= len(self._log.popleft()[1])
        return self.revision

    def _since(self, since: int) -> set[TileKey] | None:
        """The tiles changed after revision `since`, None if the log no longer reaches back."""
        if since >= self.revision:
            return set()
        if not self._log or self._log[0][0] > since + 1:
            return None
        return {k for rev, keys in self._log if rev > since for k in keys}

    def changed(self, box: TileBox, since: int = 0, held: TileBox | None = None) -> list[TileKey]:
        """The tiles in `box` an asker lacks, sorted: with `held` None, all of them; else those
        outside `held` (the asker never had them) and those changed after revision `since` (the
        asker's copy is older)."""
        recent = None if held is None else self._since(since)
        out: set[TileKey] = set()
        for (br, bc), keys in self._blocks.items():
            r0, c0 = br * BLOCK_TILES, bc * BLOCK_TILES
            part = box.intersection(TileBox(r0, r0 + BLOCK_TILES - 1, c0, c0 + BLOCK_TILES - 1))
            if part is None:
                continue
            if recent is not None and held is not None and held.covers(part):
                continue  # the asker has this part: only its changes, from `recent`, are news
            for k in keys:
                if k in box and (held is None or k not in held or self._rev[k] > since):
                    out.add(k)
        if recent is not None:
            out.update(k for k in recent if k in box and self._rev[k] > since)
        return sorted(out, key=_row_col)  # the keys' own order, without their generated __lt__


def _row_col(key: TileKey) -> tuple[int, int]:
    return key.row, key.col
