"""Every benchmark script still imports: docs/ is regenerated from them, so a script broken by a move
elsewhere (a helper that changed folder) must fail here, not months later when a figure is redone.

The scripts are imported, not run (they take minutes); one child process imports them all, with
bench/ on the path as when they run, so that they can import each other.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
BENCH = ROOT / "bench"

IMPORT_ALL = """
import importlib, sys, traceback
import matplotlib
matplotlib.use("Agg")
sys.path.insert(0, sys.argv[1])
failed = []
for name in sys.argv[2:]:
    try:
        importlib.import_module(name)
    except Exception:
        failed.append(name + ": " + traceback.format_exc(limit=2).strip().splitlines()[-1])
print("\\n".join(failed))
sys.exit(1 if failed else 0)
"""


def test_every_bench_script_imports() -> None:
    names = sorted(p.stem for p in BENCH.glob("*.py"))
    assert names, "no benchmark scripts found"
    proc = subprocess.run(
        [sys.executable, "-c", IMPORT_ALL, str(BENCH), *names],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=ROOT,
    )
    assert proc.returncode == 0, f"bench scripts that do not import:\n{proc.stdout}{proc.stderr[-2000:]}"


def test_every_bench_script_answers_help_without_running() -> None:
    """`--help` must print the usage, not start a run that rewrites a page of docs/ (one did)."""
    silent = [
        p.name
        for p in sorted(BENCH.glob("*.py"))
        if '__name__ == "__main__"' in p.read_text() and "argparse" not in p.read_text()
    ]
    assert not silent, f"scripts that run whatever their arguments: {silent}"
