"""Importing coplane limits every BLAS library to one thread (coplane/blas_threads.py), whether
numpy (and its BLAS) was loaded before or after coplane, and `COPLANE_BLAS_THREADS` overrides it."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from coplane.blas_threads import blas_threads_wanted

PROBE = """
import {first}, {second}, scipy.linalg
from threadpoolctl import threadpool_info
print(sorted({{i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"}}))
"""


def _threads(first: str, second: str, **env: str) -> str:
    clean = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "COPLANE_BLAS_THREADS")}
    out = subprocess.run(
        [sys.executable, "-c", PROBE.format(first=first, second=second)],
        env=clean | env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    return out.stdout.strip() + out.stderr.strip()


@pytest.mark.parametrize("order", [("coplane", "numpy"), ("numpy", "coplane")])
def test_every_blas_gets_one_thread(order: tuple[str, str]) -> None:
    assert _threads(*order) == "[1]"


def test_the_environment_overrides_it() -> None:
    assert _threads("numpy", "coplane", COPLANE_BLAS_THREADS="2") == "[2]"
    assert _threads("coplane", "numpy", OPENBLAS_NUM_THREADS="2") == "[2]"  # the user's own setting


def test_a_bad_setting_is_a_clear_error() -> None:
    assert blas_threads_wanted({}) == 1 and blas_threads_wanted({"COPLANE_BLAS_THREADS": ""}) is None
    for bad in ("0", "-1", "two", "²"):
        with pytest.raises(
            ValueError, match=r"COPLANE_BLAS_THREADS must be a positive integer or empty, got"
        ):
            blas_threads_wanted({"COPLANE_BLAS_THREADS": bad})
