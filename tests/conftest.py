"""Shared fixtures: where the real RINEX sets live (../shared/data/real beside the repo)."""

from __future__ import annotations

import os
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
