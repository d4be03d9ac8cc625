"""One BLAS thread per coplane process, unless `COPLANE_BLAS_THREADS` says otherwise.

coplane's linear algebra is many small matrices (a vehicle's SPP, a baseline EKF's update of at
most a few hundred rows, GAMP over a fleet state of a few dozen components), and coplane spreads
over cores with processes: vehicle workers in `coplane eval`, one agent per vehicle, fusion servers
and their cluster workers. OpenBLAS's own threads (numpy and scipy each bundle an OpenBLAS, with a
thread per core) only add synchronisation at these sizes and compete with those processes: the
dd-cp baseline, whose batch update factors a few hundred rows, ran several times as long with
them, with bit-identical positions (docs/performance.md, "BLAS threads"). Importing coplane
therefore limits every BLAS to one thread.

`COPLANE_BLAS_THREADS=N` gives N threads instead; set to an empty string it leaves the BLAS
libraries as they are (as does an `OPENBLAS_NUM_THREADS` already set by the user).
"""

from __future__ import annotations

import os
import sys
from collections.abc import Mapping

ENV = "COPLANE_BLAS_THREADS"


def blas_threads_wanted(environ: Mapping[str, str] = os.environ) -> int | None:
    """The BLAS threads per process from the environment; None: leave the BLAS alone."""
    raw = environ.get(ENV)
    if raw is None:
        return None if "OPENBLAS_NUM_THREADS" in environ else 1
    raw = raw.strip()
    if not raw:
        return None
    if not raw.isdecimal() or int(raw) < 1:  # isdecimal: what int() takes (isdigit lets '²' through)
        raise ValueError(f"environment variable {ENV} must be a positive integer or empty, got {raw!r}")
    return int(raw)


def limit_blas_threads() -> None:
    """Apply `blas_threads_wanted()`: to the BLAS libraries loaded later (and child processes)
    through OPENBLAS_NUM_THREADS, which OpenBLAS reads when it loads, and to those already loaded
    (numpy imported before coplane) through threadpoolctl."""
    n = blas_threads_wanted()
    if n is None:
        return
    os.environ["OPENBLAS_NUM_THREADS"] = str(n)
    if "numpy" in sys.modules:
        from threadpoolctl import threadpool_limits

        threadpool_limits(limits=n, user_api="blas")
