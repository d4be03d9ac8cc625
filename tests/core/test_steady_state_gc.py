"""A started service moves what it holds out of the collector's scans and scans the young
objects less often (coplane.runtime.steady_state_gc); cycles are still collected, and nothing
changes the collector of a process that only imports the services (tests, library users)."""

from __future__ import annotations

import gc
import subprocess
import sys

PROBE = """
import gc, weakref
from coplane.runtime import GC_YOUNG_THRESHOLD, steady_state_gc
steady_state_gc()
assert gc.get_threshold()[0] == GC_YOUNG_THRESHOLD, gc.get_threshold()
assert gc.get_freeze_count() > 1000, gc.get_freeze_count()

class Node:
    pass


def cycle() -> Node:
    a, b = Node(), Node()
    a.other, b.other = b, a  # a reference cycle: only the collector frees it
    return a


gone = weakref.ref(cycle())
for _ in range(GC_YOUNG_THRESHOLD):
    cycle()  # garbage that reference counting cannot free: it is what makes a collection due
print("collected" if gone() is None else "kept")
"""


def test_a_started_service_collects_cycles_with_fewer_scans() -> None:
    out = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "collected"


def test_importing_the_services_leaves_the_collector_alone() -> None:
    before = gc.get_threshold()
    import coplane.fusion_server.__main__
    import coplane.vehicle_agent.__main__  # noqa: F401

    assert gc.get_threshold() == before
