"""Valid but forged solutions against the API (issue 13): they are counted, never shape its state.

Each case is one the security review reproduced: a solution stamped a week earlier wiped the tracks
and the accuracy; a 5 km forgery left /accuracy with a 7 km maximum; (0, 0, 0) was served as
latitude 90 degrees. Payloads go through `Ingest` (decode + gate + state) as from the bus.
"""

from __future__ import annotations

import logging

import pytest
from fastapi.testclient import TestClient
from prometheus_client.parser import text_string_to_metric_families
from support.api import FLEET, T0, SyntheticFleet, ecef_at, filled_app, solution, vehicle_state

from coplane.api.state import FleetState
from coplane.bus import encode
from coplane.messages import EpochTime, SolutionMessage

GEN_A = "aaaa0000aaaa0000"
GEN_B = "bbbb1111bbbb1111"


def _week_earlier(sol: SolutionMessage, **update: object) -> SolutionMessage:
    return sol.model_copy(update={"epoch": EpochTime(week=sol.epoch.week - 1, tow=sol.epoch.tow), **update})


def _rejected(text: str) -> dict[tuple[str, str], float]:
    out = {}
    for fam in text_string_to_metric_families(text):
        for s in fam.samples:
            if s.name == "coplane_api_rejected_total":
                out[s.labels["source"], s.labels["kind"]] = s.value
    return out


def test_forgeries_leave_tracks_and_accuracy_alone(caplog: pytest.LogCaptureFixture) -> None:
    fleet = SyntheticFleet(n_vehicles=3, n_epochs=40)
    app = filled_app(fleet, epochs=30)
    ingest = app.state.ingest
    with TestClient(app) as c:
        before = (c.get("/accuracy").json(), c.get("/vehicles/v1/track").json(), c.get("/vehicles").json())
        genuine = fleet.solution(30)
        origin_off = genuine.model_copy(
            update={"vehicles": [vehicle_state("v1", (0.0, 0.0, 0.0)), *genuine.vehicles[1:]]}
        )
        caplog.set_level(logging.WARNING, logger="coplane.api")
        for _ in range(50):  # a flood: counted each time, logged rarely
            ingest.solution(encode(_week_earlier(fleet.solution(29))))
        ingest.solution(encode(_week_earlier(fleet.solution(29), generation=GEN_B)))  # "a restart"
        ingest.solution(encode(origin_off))
        ingest.solution(encode(fleet.solution(29)))  # a replay of the last epoch
        after = (c.get("/accuracy").json(), c.get("/vehicles/v1/track").json(), c.get("/vehicles").json())
        assert after[0] == before[0] and after[1] == before[1]
        assert [v["seq"] for v in after[2]["vehicles"]] == [v["seq"] for v in before[2]["vehicles"]]
        # the 5 km forgery of v1 at the next epoch: v1 is left out of it, the others are taken
        five_km = genuine.model_copy(
            update={"vehicles": [vehicle_state("v1", ecef_at(5000.0, 0.0)), *genuine.vehicles[1:]]}
        )
        ingest.solution(encode(five_km))
        for k in range(30, 40):
            ingest.solution(encode(fleet.solution(k)))  # 30 is now a duplicate
        acc = {e["vehicle_id"]: e for e in c.get("/accuracy").json()["entries"]}
        assert max(e["h_max_m"] for e in acc.values()) < 20.0  # was 7 km
        assert acc["v1"]["n_solved"] == 39 and acc["v2"]["n_solved"] == 40
        track = c.get("/vehicles/v1/track").json()["points"]
        assert len(track) == 39 and all(abs(p["lat_deg"]) < 40 for p in track)
        st = app.state.fleet
        assert st.rewinds == 0 and st.duplicates == 2  # the replayed 29, the genuine 30
        rejected = _rejected(c.get("/metrics").text)
        assert rejected[("solution", "stale")] == 50
        assert rejected[("solution", "new-generation")] == 1
        assert rejected[("solution", "off-earth")] == 1
        assert rejected[("vehicle", "vehicle-jump")] == 1
    logged = [r for r in caplog.records if r.getMessage() == "untrusted solution ignored"]
    assert 1 <= len(logged) <= 4  # counts 1 and 10 of the stale flood, the others once


def test_only_a_new_generation_after_the_old_went_quiet_resets() -> None:
    st = FleetState(FLEET)

    def sol(k: int, gen: str, e: float = 0.0) -> SolutionMessage:
        s = solution(k, T0 + float(k), [vehicle_state("a", ecef_at(e + 5.0 * k, 0))])
        return s.model_copy(update={"generation": gen})

    for k in range(10):
        assert st.on_solution(sol(k, GEN_A), 100.0 + k)
    # a forger invents a generation while the server publishes: ignored
    assert not st.on_solution(sol(0, GEN_B, e=300.0), 109.5)
    assert st.on_solution(sol(10, GEN_A), 110.0)
    assert st.rewinds == 0 and len(st.vehicles["a"].track) == 11
    # the server is restarted (a clean stop, a new run): its generation changes and it starts over
    assert st.on_solution(sol(0, GEN_B), 116.0)
    assert st.rewinds == 1 and len(st.vehicles["a"].track) == 1
    assert st.on_solution(sol(1, GEN_B), 117.0) and len(st.vehicles["a"].track) == 2
    # ...whereas a crash + resume keeps the generation: the republished last solution is a duplicate
    assert not st.on_solution(sol(1, GEN_B), 125.0)
    assert st.duplicates == 1 and st.rewinds == 1


def test_vehicle_count_and_track_length_are_capped() -> None:
    st = FleetState(FLEET, max_vehicles=5, history_per_vehicle=10)  # no recording: any id
    for k in range(30):
        states = [vehicle_state(f"f{k}-{i}", ecef_at(100.0 * i, 0)) for i in range(20)]
        st.on_solution(solution(k, T0 + float(k), [vehicle_state("a", ecef_at(k, 0)), *states]), float(k))
    assert len(st.vehicles) == 5
    assert st.rejected["vehicle", "too-many-vehicles"] > 0
    assert len(st.vehicles["a"].track) == 10
    gate = st.gate.gate("")
    assert gate is not None and gate.run is not None and len(gate.run.positions) <= 5


def test_with_a_recording_only_its_vehicles_are_taken() -> None:
    fleet = SyntheticFleet(n_vehicles=2, n_epochs=3)
    st = fleet.state()
    extra = solution(0, T0, [*fleet.solution(0).vehicles, vehicle_state("intruder", ecef_at(0, 0))])
    assert st.on_solution(extra, 0.0)
    assert sorted(st.vehicles) == fleet.ids
    assert st.rejected["vehicle", "vehicle-unknown"] == 1


def test_diagnostics_of_another_generation_are_ignored() -> None:
    fleet = SyntheticFleet(n_vehicles=2, n_epochs=3)
    st = fleet.state()
    assert st.on_diagnostics(fleet.diagnostics(0).model_copy(update={"generation": GEN_B}))  # none yet
    assert st.on_solution(fleet.solution(0).model_copy(update={"generation": GEN_A}), 0.0)
    assert not st.on_diagnostics(fleet.diagnostics(1).model_copy(update={"generation": GEN_B}))
    assert st.rejected["diagnostics", "other-generation"] == 1
    assert st.on_diagnostics(fleet.diagnostics(2).model_copy(update={"generation": GEN_A}))
    assert st.diagnostics is not None and st.diagnostics.epochs_solved == 3
