"""numpy's own arithmetic without its wrappers' overhead, for the loops a fusion server runs per
vehicle epoch on arrays of a few dozen values (issue 16: the fusion cost per vehicle-epoch).

`np.linalg.norm` normalises its arguments and dispatches on `ord` and `axis` on every call, which
costs more than the arithmetic on a (30, 3) array. These are the expressions it evaluates for the
cases used here, so the results are the same to the bit (tests/core/test_numeric.py).
"""

from __future__ import annotations

import math

import numpy as np

from coplane.typing import Vec


def row_norms(a: np.ndarray) -> Vec:
    """`np.linalg.norm(a, axis=1)` for a real 2-D array: the Euclidean length of each row."""
    return np.sqrt(np.add.reduce(a * a, axis=1))


def norm3(v: np.ndarray) -> float:
    """`float(np.linalg.norm(v))` for a real 1-D array (a position or velocity difference)."""
    return math.sqrt(float(v.dot(v)))
