"""`--fgo key=value`: factor-graph settings changed by name, parsed by type, validated by FgoConfig."""

from __future__ import annotations

import pytest

from coplane.errors import ConfigError
from coplane.fgo.config import FgoConfig
from coplane.fgo.overrides import apply_fgo_overrides, parse_fgo_overrides
from coplane.methods import get_method


def test_values_are_parsed_by_the_fields_type() -> None:
    got = parse_fgo_overrides(
        [
            "fde_k_long=1.5",
            "window_epochs=8",
            "use_planes=false",
            "solver=lm-window",
            "robust=none",
            " fde_long_below_cn0_dbhz = 35 ",
        ]
    )
    assert got == {
        "fde_k_long": 1.5,
        "window_epochs": 8,
        "use_planes": False,
        "solver": "lm-window",
        "robust": None,
        "fde_long_below_cn0_dbhz": 35.0,
    }
    assert isinstance(got["window_epochs"], int)


@pytest.mark.parametrize(
    ("item", "says"),
    [
        ("fde_k_long", "key=value"),
        ("=3", "key=value"),
        ("warp_factor=9", "no such factor-graph setting"),
        ("fde_k_long=fast", "fde_k_long=fast: expected a number"),
        ("window_epochs=2.5", "expected an integer"),
        ("use_planes=maybe", "expected true or false"),
        ("solver=magic", "expected one of lm-window"),
    ],
)
def test_a_bad_item_is_refused_by_name(item: str, says: str) -> None:
    with pytest.raises(ConfigError, match=says):
        parse_fgo_overrides([item])


def test_the_config_validates_the_changed_values() -> None:
    with pytest.raises(ConfigError, match="fde_k_long must be finite and > 0"):
        apply_fgo_overrides(FgoConfig(), parse_fgo_overrides(["fde_k_long=-1"]))


def test_a_method_changes_only_what_was_asked_and_baselines_none() -> None:
    base, changed = get_method("pc"), get_method("pc", fgo={"height_link_max_m": 50.0})
    assert base.fgo is not None and changed.fgo is not None
    assert changed.fgo.height_link_max_m == 50.0 and base.fgo.height_link_max_m == 0.0
    assert changed.fgo == FgoConfig(**{**base.fgo.__dict__, "height_link_max_m": 50.0})
    assert get_method("gamp-cp", fgo={"fde_k_long": 2.5}) == get_method("gamp-cp")
