"""The memory allocator of the services coplane starts: jemalloc where the machine has it.

GTSAM's iSAM2 allocates and frees many small objects on every update (factors, noise models,
linearised factors, Bayes-tree cliques), and smoothers are dropped and rebuilt as clusters change.
glibc's malloc serves that pattern measurably slower than jemalloc: the fusion estimator alone ran
a 1000-vehicle city on 0.81 times glibc's CPU with jemalloc, with bit-identical positions
(docs/performance-scale.md, "Memory allocator"; `bench/bench_allocator.py`). A running process
cannot change its allocator, so the library is preloaded (`LD_PRELOAD`) into the processes
coplane starts (`coplane.fleet.launcher`, and the cluster processes a server spawns inherit it);
the Docker image preloads it for its own.

`COPLANE_ALLOCATOR`: "auto" (the default: jemalloc if the dynamic linker finds it, else the
system's malloc), "system" (leave malloc alone), or the path of an allocator library to preload.
Written here because nothing in the Python ecosystem picks an allocator for child processes;
jemalloc itself comes from the system (Debian `libjemalloc2`, installed by scripts/setup.sh).
"""

from __future__ import annotations

import ctypes.util
import functools
import os
import sys
from collections.abc import Mapping
from pathlib import Path

from coplane.errors import ConfigError

ENV = "COPLANE_ALLOCATOR"


@functools.cache
def _find_jemalloc() -> str | None:
    """jemalloc as the dynamic linker will find it by name (ldconfig's cache), or None."""
    return ctypes.util.find_library("jemalloc")


def allocator_library(environ: Mapping[str, str] = os.environ) -> str | None:
    """The allocator library to preload into coplane's services; None: the system's malloc."""
    raw = environ.get(ENV, "auto").strip()
    if raw == "system" or not sys.platform.startswith("linux"):
        return None
    if raw in ("", "auto"):
        return _find_jemalloc()
    if not Path(raw).is_file():
        raise ConfigError(f"environment variable {ENV}: {raw!r} is not 'auto', 'system' or a library file")
    return raw


def allocator_env(environ: Mapping[str, str] = os.environ) -> dict[str, str]:
    """The environment entries that make a child process use `allocator_library()`: LD_PRELOAD
    with the allocator first and whatever `environ` already preloads after it; {} for none."""
    lib = allocator_library(environ)
    if lib is None:
        return {}
    current = [p for p in environ.get("LD_PRELOAD", "").replace(" ", ":").split(":") if p]
    if any(Path(p).name == Path(lib).name for p in current):  # already preloaded, by name or path
        return {}
    return {"LD_PRELOAD": ":".join([lib, *current])}


def loaded_allocator(maps: Path = Path("/proc/self/maps")) -> str:
    """Which allocator this process runs on ("jemalloc", "tcmalloc", "mimalloc", "tbbmalloc"
    or "system"), from its memory map: for benchmarks and diagnostics to say what they measured."""
    try:
        text = maps.read_text()
    except OSError:
        return "unknown"
    for name in ("jemalloc", "tcmalloc", "mimalloc", "tbbmalloc"):
        if f"lib{name}" in text:
            return name
    return "system"
