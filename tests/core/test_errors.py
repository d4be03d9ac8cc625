"""`coplane.errors.require_finite_positive`, the one check of the option classes' rates and sigmas."""

from __future__ import annotations

import math

import numpy as np
import pytest

from coplane.baselines.fleet_filter import EkfConfig
from coplane.baselines.gamp_cp import GampConfig
from coplane.fgo.config import FgoConfig
from coplane.gnss.doppler import DopplerOptions
from coplane.plane.config import PlaneConfig
from coplane.roadmap.config import RoadMapConfig


@pytest.mark.parametrize("bad", [0.0, -1.0, math.nan, math.inf, "1.0", True, None])
@pytest.mark.parametrize(
    ("cls", "field", "prefix"),
    [
        (FgoConfig, "sigma_v", ""),
        (FgoConfig, "coop_fde_radius_m", ""),
        (GampConfig, "range_sigma", ""),
        (PlaneConfig, "t_f_m", "PlaneConfig."),
        (RoadMapConfig, "cusum_h", "RoadMapConfig."),
        (EkfConfig, "accel_psd_h", ""),
        (DopplerOptions, "few_max_sigma_mps", "DopplerOptions."),
    ],
)
def test_a_field_that_is_not_a_positive_number_is_named(
    cls: type, field: str, prefix: str, bad: object
) -> None:
    """Zero, negative, NaN, infinite, a string or a boolean (as a file could give them): a
    ValueError that names the class's field, never a TypeError or a silently accepted value."""
    with pytest.raises(ValueError, match=f"^{prefix}{field} must be finite and > 0"):
        cls(**{field: bad})


def test_numpy_numbers_and_optional_thresholds_pass() -> None:
    """numpy scalars are numbers; an optional threshold set to None is off, not invalid."""
    assert FgoConfig(sigma_v=np.float32(0.2), fde_k=None).sigma_v == pytest.approx(0.2)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"^fde_k must be finite and > 0"):
        FgoConfig(fde_k=-3.0)
    assert FgoConfig(clock_drift_wander=None).clock_drift_wander is None
    with pytest.raises(ValueError, match=r"^clock_drift_wander must be finite and > 0"):
        FgoConfig(clock_drift_wander=math.nan)
