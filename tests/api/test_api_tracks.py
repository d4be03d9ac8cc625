"""Track files other tools read (issue 15): GET /vehicles/{id}/track.geojson, .gpx and .pos."""

from __future__ import annotations

import datetime as dt
from pathlib import Path

import gpxpy
import numpy as np
import pytest
from fastapi.testclient import TestClient
from support.api import SyntheticFleet, filled_app

from coplane.api import views
from coplane.gtime import GpsTime, gpst_to_utc
from coplane.recording.problems import Problems
from coplane.recording.trajectories import Q_DGPS, Q_DR, Q_SINGLE, read_pos


@pytest.fixture(scope="module")
def fleet() -> SyntheticFleet:
    return SyntheticFleet(n_vehicles=3, n_epochs=20)


def test_geojson_and_gpx_tracks_hold_the_json_track(fleet: SyntheticFleet) -> None:
    app = filled_app(fleet)
    with TestClient(app) as c:
        tr = c.get("/vehicles/v1/track", params={"limit": 12}).json()["points"]
        r = c.get("/vehicles/v1/track.geojson", params={"limit": 12})
        assert r.status_code == 200 and r.headers["content-type"].startswith("application/geo+json")
        coords = r.json()["features"][0]["geometry"]["coordinates"]
        assert coords == [[p["lon_deg"], p["lat_deg"], p["height_m"]] for p in tr]
        r = c.get("/vehicles/v1/track.gpx", params={"limit": 12})
        assert r.status_code == 200 and r.headers["content-type"].startswith("application/gpx+xml")
        gpx = gpxpy.parse(r.text)
        (seg,) = gpx.tracks[0].segments
        assert len(seg.points) == 12
        for gp, p in zip(seg.points, tr, strict=True):
            assert gp.latitude == pytest.approx(p["lat_deg"], abs=1e-9)
            assert gp.longitude == pytest.approx(p["lon_deg"], abs=1e-9)
            assert gp.elevation == pytest.approx(p["height_m"], abs=1e-3)
            utc = gpst_to_utc(GpsTime(p["week"], p["tow"])).replace(tzinfo=dt.UTC)
            assert gp.time == utc
        assert c.get("/vehicles/nobody/track.gpx").status_code == 404
        assert c.get("/vehicles/v1/track.gpx", params={"limit": 0}).status_code == 422
    assert views.track_gpx(app.state.fleet, "v1", limit=1) is not None


def test_pos_track_holds_the_json_track(fleet: SyntheticFleet, tmp_path: Path) -> None:
    """RTKLIB's layout: coplane's own reader and RTKLIB's `readsol` (pyrtklib) read the positions,
    Q by what carried each epoch (as `coplane eval --format pos`), and ns the pseudoranges kept."""
    app = filled_app(fleet)
    with TestClient(app) as c:
        tr = c.get("/vehicles/v1/track", params={"limit": 12}).json()["points"]
        r = c.get("/vehicles/v1/track.pos", params={"limit": 12})
        assert r.status_code == 200 and r.headers["content-type"].startswith("text/plain")
        assert c.get("/vehicles/nobody/track.pos").status_code == 404
        assert c.get("/vehicles/v1/track.pos", params={"limit": 0}).status_code == 422
    path = tmp_path / "v1.pos"
    path.write_text(r.text)
    pos = read_pos(path, Problems())
    assert len(pos) == 12
    for got, p in zip(pos, tr, strict=True):
        assert (got.time.week, got.time.tow) == (p["week"], pytest.approx(p["tow"], abs=1e-3))
        assert np.allclose(got.ecef, p["position_ecef_m"], atol=1e-3)
        want_q = Q_DR if not p["has_gnss_fix"] else Q_SINGLE if p["dgnss_age_s"] is None else Q_DGPS
        assert (got.quality, got.n_sats) == (want_q, p["n_pseudoranges"])
    import pyrtklib  # a dev dependency (pyproject.toml): missing, the test fails

    buf = pyrtklib.solbuf_t()
    assert pyrtklib.readsol([str(path)], 1, buf) == 1 and buf.n == 12
