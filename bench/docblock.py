"""The generated blocks of the docs pages: `<!-- NAME:start -->` ... `<!-- NAME:end -->`.

Benchmarks rewrite only their own block, headed by the date and the exact command that made it,
so a page can hold several tables and the prose around them is never touched.
"""

from __future__ import annotations

import os
import platform
import sys
import time
from pathlib import Path

_REEXEC = "COPLANE_BENCH_ON_SERVICE_ALLOCATOR"


def on_service_allocator() -> str:
    """Run this benchmark on the allocator coplane's services run on (`coplane.allocator`:
    jemalloc where installed), so that its CPU figures are theirs. A process cannot change its
    allocator, so the script runs itself again, once, with it preloaded. Returns the allocator
    this process runs on, for the table's header."""
    from coplane.allocator import allocator_env, loaded_allocator

    env = allocator_env()
    if env and os.environ.get(_REEXEC) != "1":
        sys.stdout.flush()
        os.execve(sys.executable, [sys.executable, *sys.argv], {**os.environ, **env, _REEXEC: "1"})
    return loaded_allocator()


def machine(cpus: bool = True) -> str:
    """'x86_64, 2 CPUs, Python 3.11.7': where a table was made, for its header line."""
    count = f", {os.cpu_count()} CPUs" if cpus else ""
    return f"{platform.machine()}{count}, Python {platform.python_version()}"


def write_block(path: Path, marker: str, command: str, body: str) -> None:
    """Replace block `marker` of `path` with `body`, headed by today's date and `command`; the
    block must exist (a typo in a marker must not append a stray table)."""
    start, end = f"<!-- {marker}:start -->", f"<!-- {marker}:end -->"
    text = path.read_text()
    block = f"{start}\nMade on {time.strftime('%Y-%m-%d')} by `{command}`:\n\n{body}\n{end}"
    i, j = text.index(start), text.index(end) + len(end)
    path.write_text(text[:i] + block + text[j:])


def publish(out: Path | None, marker: str, command: str, head: str, rows: list[str]) -> str:
    """A table (a header line, then its Markdown rows) printed, and written to block `marker` of
    `out` when one is given; returns the table."""
    table = head + "\n\n" + "\n".join(rows)
    print(table)
    if out is not None:
        write_block(out, marker, command, table)
    return table
