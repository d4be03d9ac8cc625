"""The HTTP layer in-process: every endpoint on a pre-filled state, problem details, CORS, metrics
text, and the SSE stream through a real uvicorn server (in a thread)."""

from __future__ import annotations

import json
import time

import httpx
import pytest
from fastapi.testclient import TestClient
from prometheus_client.parser import text_string_to_metric_families
from support.api import FLEET, SyntheticFleet, feed, filled_app, serve

from coplane.api import views
from coplane.api.app import create_app
from coplane.api.bus_client import LocalBus
from coplane.api.models import StreamEvent
from coplane.api.settings import ApiSettings


@pytest.fixture(scope="module")
def fleet() -> SyntheticFleet:
    return SyntheticFleet(n_vehicles=4, n_epochs=50)


def _metrics(text: str) -> dict[tuple[str, tuple[tuple[str, str], ...]], float]:
    out = {}
    for fam in text_string_to_metric_families(text):
        for s in fam.samples:
            out[s.name, tuple(sorted(s.labels.items()))] = s.value
    return out


def test_endpoints_on_a_filled_state(fleet: SyntheticFleet) -> None:
    bus = LocalBus()
    app = filled_app(fleet, bus=bus)
    st = app.state.fleet
    with TestClient(app) as c:
        vl = c.get("/vehicles").json()
        assert vl["fleet"] == FLEET and [v["vehicle_id"] for v in vl["vehicles"]] == fleet.ids
        last = fleet.solution(fleet.n_epochs - 1)
        for v, vs in zip(vl["vehicles"], last.vehicles, strict=True):
            assert v["position_ecef_m"] == list(vs.position_ecef_m)
            assert v["seq"] == fleet.n_epochs - 1
        assert [v["online"] for v in vl["vehicles"]] == [True, True, True, False]
        d = c.get("/vehicles/v2").json()
        assert d["covariance_m2"] == list(last.vehicles[1].covariance_m2 or [])
        assert d["counters"]["received"] == fleet.n_epochs + 3 and d["server_online"] is True
        assert d["track_points"] == fleet.n_epochs
        tr = c.get("/vehicles/v2/track", params={"since": views.track(st, "v2").points[-5].gps_s}).json()
        assert len(tr["points"]) == 4
        r = c.get("/vehicles/v2/track", params={"format": "geojson", "limit": 10})
        assert r.headers["content-type"].startswith("application/geo+json")
        gj = r.json()
        assert gj["type"] == "FeatureCollection" and len(gj["features"][0]["geometry"]["coordinates"]) == 10
        assert gj["features"][0]["geometry"]["coordinates"][-1][0] == pytest.approx(
            tr["points"][-1]["lon_deg"]
        )
        pl = c.get("/planes").json()
        assert sum(pl["now"].values()) == 4 and len(pl["vehicles"]) == 4
        acc = c.get("/accuracy").json()
        assert {e["vehicle_id"] for e in acc["entries"]} == set(fleet.ids)
        assert all(e["n_solved"] == fleet.n_epochs and e["availability"] == 1.0 for e in acc["entries"])
        assert len(c.get("/accuracy", params={"vehicle_id": "v3"}).json()["entries"]) == 1
        assert c.get("/accuracy", params={"method": "other"}).json()["entries"] == []
        assert c.get("/healthz").json()["status"] == "ok"
        assert c.get("/readyz").status_code == 200
        bus.is_connected = False
        r = c.get("/readyz")
        assert r.status_code == 503 and r.json()["reasons"] == ["not connected to a Zenoh router"]
        html = c.get("/")
        assert html.headers["content-type"].startswith("text/html") and "EventSource" in html.text
        assert "//cdn" not in html.text and 'src="http' not in html.text  # no internet needed


def test_problem_details_and_openapi(fleet: SyntheticFleet) -> None:
    app = filled_app(fleet, epochs=3)
    with TestClient(app) as c:
        for url, code in [
            ("/vehicles/nobody", 404),
            ("/vehicles/bad%20id", 422),
            ("/vehicles/v1/track?limit=0", 422),
            ("/vehicles/v1/track?since=nan", 422),
            ("/vehicles/v1/track?format=kml", 422),
            ("/no/such/path", 404),
        ]:
            r = c.get(url)
            assert r.status_code == code, url
            assert r.headers["content-type"] == "application/problem+json", url
            p = r.json()
            assert (
                p["status"] == code and p["title"] and p["instance"] == url.split("?")[0].replace("%20", " ")
            )
        assert c.post("/vehicles").status_code == 405
        spec = c.get("/openapi.json").json()
        paths = spec["paths"]
        for p in [
            "/vehicles",
            "/vehicles/{vehicle_id}",
            "/vehicles/{vehicle_id}/track",
            "/planes",
            "/accuracy",
        ]:
            assert "$ref" in json.dumps(paths[p]["get"]["responses"]["200"]), p
        for p in ["/stream", "/metrics", "/healthz", "/readyz", "/"]:
            assert p in paths
        err = paths["/vehicles/{vehicle_id}"]["get"]["responses"]["404"]["content"]
        assert list(err) == ["application/problem+json"]
        assert (
            "application/geo+json"
            in paths["/vehicles/{vehicle_id}/track"]["get"]["responses"]["200"]["content"]
        )
        assert "HTTPValidationError" not in spec["components"]["schemas"]
        assert "StreamEvent" in spec["components"]["schemas"]
        assert not any(op != "get" for ops in paths.values() for op in ops)  # read-only API


def test_cors_is_off_by_default_and_configurable(fleet: SyntheticFleet) -> None:
    with TestClient(filled_app(fleet, epochs=1)) as c:
        r = c.get("/vehicles", headers={"Origin": "http://elsewhere"})
        assert "access-control-allow-origin" not in r.headers
    st = fleet.state()
    app = create_app(ApiSettings(fleet=FLEET, cors_origins=["http://ops.example"]), LocalBus(), state=st)
    with TestClient(app) as c:
        r = c.get("/vehicles", headers={"Origin": "http://ops.example"})
        assert r.headers["access-control-allow-origin"] == "http://ops.example"


def test_metrics_text(fleet: SyntheticFleet) -> None:
    app = filled_app(fleet)
    with TestClient(app) as c:
        r = c.get("/metrics")
        assert r.status_code == 200 and r.headers["content-type"].startswith("text/plain")
        m = _metrics(r.text)
    n = fleet.n_epochs
    for vid in fleet.ids:
        assert m["coplane_messages_received_total", (("vehicle", vid),)] == n + 3
        assert m["coplane_messages_rejected_total", (("vehicle", vid),)] == 1
        assert m["coplane_messages_late_total", (("vehicle", vid),)] == 1
        assert 0.0 <= m["coplane_plane_availability_ratio", (("vehicle", vid),)] <= 1.0
    assert m["coplane_messages_rejected_by_reason_total", (("reason", "invalid-json"),)] == 4
    assert m["coplane_solve_time_seconds_count", ()] == n
    assert m["coplane_epoch_latency_seconds_count", ()] == n
    assert m["coplane_epoch_latency_seconds_bucket", (("le", "0.025"),)] == n  # stamped 10 ms before
    assert m["coplane_live_vehicles", ()] == 4
    assert m["coplane_vehicle_online", (("vehicle", "v4"),)] == 0
    assert m["coplane_api_solutions_total", ()] == n
    assert m["coplane_api_ready", ()] == 1
    assert m["coplane_fusion_servers_alive", ()] == 1
    assert m["coplane_fusion_cluster_workers", (("server", ""), ("state", "running"))] == 2
    assert m["coplane_fusion_cluster_workers", (("server", ""), ("state", "lost"))] == 1
    assert m["coplane_map_common_offset_metres", (("server", ""),)] == 0.25
    assert m["coplane_map_evidence_total", (("kind", "skipped:sigma-up"), ("server", ""))] == 3
    assert m["coplane_map_evidence_total", (("kind", "passes_added"), ("server", ""))] == 6


def test_sse_stream_delivers_solutions_and_limits_clients(fleet: SyntheticFleet) -> None:
    app = filled_app(fleet, epochs=5)
    app.state.hub.max_clients = 1
    with serve(app) as url, httpx.Client(base_url=url, timeout=10) as c:
        seen: list[StreamEvent] = []
        with c.stream("GET", "/stream") as r:
            assert r.status_code == 200 and r.headers["content-type"].startswith("text/event-stream")
            busy = c.get("/stream")
            assert busy.status_code == 503 and busy.headers["content-type"] == "application/problem+json"
            feed(app, fleet, 5, 12, 0.02)
            event = None
            t0 = time.monotonic()
            for line in r.iter_lines():
                if line.startswith("event:"):
                    event = line.split(":", 1)[1].strip()
                elif line.startswith("data:"):
                    assert event == "solution"
                    seen.append(StreamEvent.model_validate_json(line[5:]))
                    if seen[-1].seq == 11 or time.monotonic() - t0 > 10:
                        break
        assert [e.seq for e in seen] == list(range(4, 12))  # the latest first, then each new one
        last = seen[-1]
        assert len(last.vehicles) == 4 and last.fleet == FLEET
        assert last.latency_s is not None and 0.0 <= last.latency_s < 5.0
        v1 = views.vehicle_detail(app.state.fleet, "v1", time.time())
        assert last.vehicles[0].enu_m == pytest.approx(v1.enu_m)
        assert app.state.fleet.solutions == 12
