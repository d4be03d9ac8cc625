"""Shared fixtures: where the real RINEX sets live (../shared/data/real beside the repo), a
private state directory for the whole run, and unique node ids for pytest-xdist."""

from __future__ import annotations

import os
import shutil
import tempfile
from collections import Counter
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
REAL_DATA = Path(os.environ.get("COPLANE_REAL_DATA", REPO.parent / "shared" / "data" / "real"))


@pytest.fixture(scope="session")
def real_data() -> Path:
    """The real-data folder. Its absence is a failure, not a skip: CI always has it."""
    if not REAL_DATA.is_dir():
        pytest.fail(f"real RINEX data not found at {REAL_DATA} (set COPLANE_REAL_DATA)")
    return REAL_DATA


_STATE_DIR: str | None = None


def pytest_configure(config: pytest.Config) -> None:
    """Services started by tests (in-process or as children, which inherit the environment) keep
    their solution logs in a fresh directory, never in the user's ~/.local/state/coplane: a test
    must not resume from another run's log, nor leave files behind."""
    global _STATE_DIR
    _STATE_DIR = tempfile.mkdtemp(prefix="coplane-test-state-")
    os.environ["COPLANE_STATE_DIR"] = _STATE_DIR


def pytest_unconfigure(config: pytest.Config) -> None:
    if _STATE_DIR is not None:
        shutil.rmtree(_STATE_DIR, ignore_errors=True)


def _scope(item: pytest.Item) -> str:
    """The unit pytest-xdist's loadscope hands to one worker: the module, or the test class."""
    return item.nodeid.rsplit("::", 1)[0]


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Prepare the suite for scripts/test.sh, which splits it over processes with pytest-xdist:

    - Scopes with a `slow` test run first (xdist hands scopes out in collection order with
      `--no-loadscope-reorder`): the minutes-long benchmarks start at once on separate workers
      instead of ending the run on one while the others idle. A scope's tests stay together, so a
      single process still builds each module fixture once.
    - Tests that share a node id get their own: xdist's scheduler keys tests by node id, and
      schemathesis' generated tests (one per API operation) all carry their function's id, so xdist
      ran one of the 14.
    """
    slow = {_scope(item) for item in items if item.get_closest_marker("slow")}
    items.sort(key=lambda item: _scope(item) not in slow)  # stable: collection order otherwise
    shared = Counter(item.nodeid for item in items)
    for item in items:
        if shared[item.nodeid] < 2 or item.parent is None:
            continue
        if hasattr(item, "_id"):  # pytest >= 9: the id pytest itself gives a child node
            item._id = item.parent.id.child(item.name)
        else:
            item._nodeid = f"{item.parent.nodeid}::{item.name}"
