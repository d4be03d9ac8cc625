"""RoadMapConfig: validated on construction, errors name the field; round trip through a dict."""

from __future__ import annotations

import dataclasses
import json
import math

import pytest

from coplane.roadmap import RoadMapConfig


@pytest.mark.parametrize(
    "field, value",
    [
        ("tile_size_m", 0.0),
        ("tile_size_m", 5000.0),
        ("slope_prior_sigma", -0.1),
        ("roughness_sigma_m", 0.0),
        ("max_sigma_up_m", math.nan),
        ("max_sigma_h_m", math.inf),
        ("pass_gap_s", 0.0),
        ("outlier_z", -1.0),
        ("cusum_k", -0.5),
        ("cusum_h", 0.0),
        ("recent_passes", 0),
        ("recent_passes", 2.5),
        ("half_life_s", 0.0),
        ("half_life_s", math.nan),
        ("min_passes", 0),
        ("max_use_sigma_m", 0.0),
        ("change_reference", "yes"),
        ("change_reference", 1),
        ("change_reference_window_s", 0.0),
        ("change_reference_window_s", math.inf),
        ("change_reference_passes", 0),
        ("change_reference_min_passes", -3),
    ],
)
def test_invalid_values_name_the_field(field: str, value: float) -> None:
    with pytest.raises(ValueError, match=f"RoadMapConfig.{field} "):
        dataclasses.replace(RoadMapConfig(), **{field: value})


def test_round_trip_through_json_ignores_unknown_keys() -> None:
    cfg = RoadMapConfig(tile_size_m=25.0, half_life_s=math.inf, recent_passes=8)
    d = json.loads(json.dumps(cfg.to_dict()))
    assert RoadMapConfig.from_dict({**d, "from_a_newer_version": 1}) == cfg
    assert RoadMapConfig(half_life_s=math.inf).half_life_s == math.inf  # no decay is allowed
