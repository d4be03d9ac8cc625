"""Property-based tests against the OpenAPI spec (schemathesis): for generated valid and invalid
requests, no 5xx, and every response matches its documented status, media type and schema.

Runs in-process (ASGI) against an app whose state holds a synthetic four-vehicle fleet, so the
responses carry real content. /stream is excluded here (an endless response; see test_api_http).
"""

from __future__ import annotations

import schemathesis
from hypothesis import HealthCheck, settings
from schemathesis.config import SchemathesisConfig
from support.api import SyntheticFleet, filled_app

APP = filled_app(SyntheticFleet(n_vehicles=4, n_epochs=30))
CONFIG = SchemathesisConfig.from_dict(
    {
        "generation": {"max-examples": 40, "mode": "all"},
        # a bbox's rules (min below max, at most 0.5 degrees a side) are not expressible in OpenAPI:
        # a schema-valid box may rightly get 422; every other check still runs on /map/tiles
        "operations": [
            {"include-path": "/map/tiles", "checks": {"positive_data_acceptance": {"enabled": False}}}
        ],
    }
)
schema = schemathesis.openapi.from_asgi("/openapi.json", APP, config=CONFIG).exclude(path="/stream")


@schema.parametrize()
@settings(deadline=None, suppress_health_check=list(HealthCheck))
def test_openapi_conformance(case: schemathesis.Case) -> None:
    case.call_and_validate()


def test_vehicle_ids_from_the_state_hit_real_data() -> None:
    """Random ids mostly miss; check the documented 200 shapes with the fleet's own ids too."""
    op = schema["/vehicles/{vehicle_id}/track"]["GET"]
    for vid in ("v1", "v4"):
        for fmt in ("json", "geojson"):
            case = op.Case(path_parameters={"vehicle_id": vid}, query={"format": fmt, "limit": 5})
            resp = case.call_and_validate()
            assert resp.status_code == 200
    case = schema["/vehicles/{vehicle_id}"]["GET"].Case(path_parameters={"vehicle_id": "v2"})
    assert case.call_and_validate().status_code == 200
