"""coplane.numeric: numpy's norms without their wrappers, equal to the bit (the fusion server's
per-epoch loops use them, and its solutions must not move: docs/performance-scale.md)."""

from __future__ import annotations

import numpy as np
import pytest

from coplane.numeric import norm3, row_norms


@pytest.mark.filterwarnings("ignore:overflow encountered")
@pytest.mark.parametrize("scale", [1e-3, 1.0, 2.6e7, 1e200])
def test_row_norms_equal_numpy_to_the_bit(scale: float) -> None:
    rng = np.random.default_rng(7)
    a = rng.normal(size=(40, 3)) * scale
    assert np.array_equal(row_norms(a), np.linalg.norm(a, axis=1))
    assert row_norms(np.empty((0, 3))).shape == (0,)


@pytest.mark.filterwarnings("ignore:overflow encountered")
@pytest.mark.parametrize("scale", [1e-3, 1.0, 6.4e6, 1e200])
def test_norm3_equals_numpy_to_the_bit(scale: float) -> None:
    rng = np.random.default_rng(8)
    for v in rng.normal(size=(200, 3)) * scale:
        assert norm3(v) == float(np.linalg.norm(v))
    assert isinstance(norm3(np.array([3.0, 4.0, 0.0])), float)
