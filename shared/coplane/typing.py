"""Type aliases used across coplane: one definition instead of one per module."""

from __future__ import annotations

from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

Vec = NDArray[np.float64]  # a float vector (often ECEF metres, shape (3,))
Mat = NDArray[np.float64]  # a float matrix (covariances, Jacobians, stacked vectors)
AnyArray = NDArray[Any]  # an array of any dtype (ids, flags)
Pace = Literal["lockstep", "realtime"]  # epochs as fast as the fleet solves them, or at the clock's
