"""The API's accepted-solutions log: tracks after a restart equal those before (services/api/history.py)."""

from __future__ import annotations

from pathlib import Path

from support.api import FLEET, SyntheticFleet

from coplane.api import views
from coplane.api.history import open_history
from coplane.api.settings import ApiSettings


def _tracks(state, ids):  # type: ignore[no-untyped-def]
    return {v: views.track(state, v, None, None) for v in ids}


def test_tracks_and_accuracy_come_back_after_a_crash(tmp_path: Path) -> None:
    fleet = SyntheticFleet(n_vehicles=3, n_epochs=30)
    settings = ApiSettings(fleet=FLEET, db=str(tmp_path / "api.sqlite"))
    before = fleet.state()
    h = open_history(settings, before)
    assert h is not None
    for k in range(20):
        assert before.on_solution(fleet.solution(k), 1000.0 + k)
    assert not before.on_solution(fleet.solution(19), 1020.0)  # a repeat is not taken, nor logged
    h.log.db.close()  # kill -9: no clean close
    h.log._release()

    after = fleet.state()
    h2 = open_history(settings, after)
    assert h2 is not None
    assert _tracks(after, fleet.ids) == _tracks(before, fleet.ids)
    assert views.accuracy_report(after) == views.accuracy_report(before)
    assert views.vehicle_list(after, 2000.0) == views.vehicle_list(before, 2000.0)
    assert after.solutions == before.solutions and after.last_t == before.last_t
    for k in range(20, 30):  # and it keeps recording
        after.on_solution(fleet.solution(k), 1000.0 + k)
    assert h2.log.count() == 30
    h2.close()


def test_db_none_keeps_no_history(tmp_path: Path) -> None:
    fleet = SyntheticFleet(n_vehicles=1, n_epochs=1)
    assert open_history(ApiSettings(fleet=FLEET, db="none"), fleet.state()) is None
