"""The generated blocks of the docs pages: `<!-- NAME:start -->` ... `<!-- NAME:end -->`.

Benchmarks rewrite only their own block, headed by the date and the exact command that made it,
so a page can hold several tables and the prose around them is never touched.
"""

from __future__ import annotations

import time
from pathlib import Path


def write_block(path: Path, marker: str, command: str, body: str) -> None:
    """Replace block `marker` of `path` with `body`, headed by today's date and `command`; the
    block must exist (a typo in a marker must not append a stray table)."""
    start, end = f"<!-- {marker}:start -->", f"<!-- {marker}:end -->"
    text = path.read_text()
    block = f"{start}\nMade on {time.strftime('%Y-%m-%d')} by `{command}`:\n\n{body}\n{end}"
    i, j = text.index(start), text.index(end) + len(end)
    path.write_text(text[:i] + block + text[j:])
