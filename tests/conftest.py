"""Shared fixtures: where the real RINEX sets live (../shared/data/real beside the repo), and a
private state directory for the whole run."""

from __future__ import annotations

import os
import shutil
import tempfile
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
