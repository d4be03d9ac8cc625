"""The suite can be split over processes (scripts/test.sh, pytest-xdist): every test has a node id
of its own, or xdist's scheduler, which keys tests by node id, runs one test per shared id."""

from __future__ import annotations

import subprocess
import sys
from collections import Counter
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def test_every_node_id_is_unique() -> None:
    res = subprocess.run(
        [sys.executable, "-m", "pytest", "--collect-only", "-q", "-p", "no:cacheprovider", "tests"],
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=300,
    )
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-2000:]
    ids = [line for line in res.stdout.splitlines() if "::" in line]
    assert any("test_openapi_conformance[" in i for i in ids)  # schemathesis' tests, one per operation
    shared = [i for i, n in Counter(ids).items() if n > 1]
    assert not shared, shared
