"""The service entry points turn a user-fixable problem into one line and an exit code."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
RECORDING = REPO / "shared" / "coplane" / "data" / "recordings" / "default"


def test_a_corrupt_solution_log_is_one_line_and_exit_2_not_a_traceback(tmp_path: Path) -> None:
    db = tmp_path / "log.sqlite"
    db.write_bytes(b"not a database " * 100)
    r = subprocess.run(
        [sys.executable, "-m", "coplane.fusion_server", "--recording", str(RECORDING), "--db", str(db)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr
    assert f"{db}: not a usable SQLite log" in r.stderr


def test_a_missing_recording_is_named(tmp_path: Path) -> None:
    r = subprocess.run(
        [sys.executable, "-m", "coplane.vehicle_agent", "--recording", str(tmp_path), "--vehicle_id", "u1"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr and "fleet.toml" in r.stderr


def test_the_api_names_a_corrupt_log_before_serving(tmp_path: Path) -> None:
    db = tmp_path / "api.sqlite"
    db.write_bytes(b"not a database " * 100)
    r = subprocess.run(
        [sys.executable, "-m", "coplane.api", "--recording", str(RECORDING), "--db", str(db), "--port", "0"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr
    assert f"{db}: not a usable SQLite log" in r.stderr
