"""Run code in a fresh interpreter: what a process loads at start can only be seen in one that
has imported nothing yet (the test process has imported everything)."""

from __future__ import annotations

import subprocess
import sys


def fresh_python(code: str) -> str:
    """The stripped standard output of `python -c code` in a new process (this interpreter and
    environment); a failure raises with the child's error output."""
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    if done.returncode != 0:
        raise AssertionError(f"python -c failed ({done.returncode}):\n{done.stderr}")
    return done.stdout.strip()
