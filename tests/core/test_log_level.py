"""A service's log level is checked with its other settings: a typo names the field at start."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from coplane.api.settings import ApiSettings
from coplane.fusion_server.settings import FusionSettings
from coplane.vehicle_agent.settings import AgentSettings, LoadgenSettings


@pytest.mark.parametrize("cls", [FusionSettings, AgentSettings, LoadgenSettings, ApiSettings])
def test_log_levels_are_checked_and_any_case_is_taken(cls: type) -> None:
    required = {
        k: v for k, v in {"recording": "/nonexistent", "vehicle_id": "v1"}.items() if k in cls.model_fields
    }
    assert cls(**required, log_level="debug").log_level == "DEBUG"
    with pytest.raises(ValidationError, match="'verbose' is not a log level"):
        cls(**required, log_level="verbose")
