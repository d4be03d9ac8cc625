"""The dashboard in headless Chromium: vehicles drawn, and updated from the SSE stream.

The app (served by uvicorn in a thread) holds 40 epochs of a synthetic four-vehicle fleet and a
feeder keeps publishing new solutions through Ingest, as the Zenoh subscriber would. The page is
opened with `?events=8` so it closes its stream after eight events; then Chromium's virtual time
can run out and it writes the screenshot and the DOM. The screenshot goes to the test's tmp dir;
with COPLANE_UPDATE_DOCS=1 it also replaces docs/img/dashboard.png (a test does not rewrite tracked
files by default). Chromium is a Debian package installed by scripts/setup.sh: without it
this test fails (a dashboard nobody looked at is not tested).
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from matplotlib.image import imread
from support.api import SyntheticFleet, feed, filled_app, serve

REPO = Path(__file__).resolve().parents[2]
PLANE_COLORS = {"available": "#2e9d4f", "available-after-fe": "#d99a00", "unavailable": "#d23c3c"}


def _chromium() -> str:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    pytest.fail(
        "headless Chromium is needed for the dashboard test: `apt-get install -y chromium` "
        "(scripts/setup.sh does it when run as root)"
    )


def _pixels_near(img: np.ndarray, hex_color: str, tol: float = 0.08) -> int:
    rgb = np.array([int(hex_color[i : i + 2], 16) / 255 for i in (1, 3, 5)])
    return int(np.all(np.abs(img[..., :3] - rgb) < tol, axis=-1).sum())


def test_dashboard_draws_vehicles_and_follows_the_stream(tmp_path: Path) -> None:
    browser = _chromium()
    fleet = SyntheticFleet(n_vehicles=4, n_epochs=600)
    app = filled_app(fleet, epochs=40)
    shot = tmp_path / "dashboard.png"
    with serve(app) as url:
        feed(app, fleet, 40, 600, 0.05)
        cmd = [
            browser,
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-quic",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--hide-scrollbars",
            f"--user-data-dir={tmp_path / 'profile'}",
            f"--screenshot={shot}",
            "--window-size=1200,800",
            "--virtual-time-budget=3000",
            "--dump-dom",
            f"{url}/?events=8",
        ]
        out = subprocess.run(cmd, capture_output=True, text=True, timeout=90)
    assert out.returncode == 0, out.stderr[-2000:]
    dom = out.stdout
    body = re.search(r"<body[^>]*>", dom)
    assert body is not None, dom[:500]
    assert 'data-sse-events="8"' in body.group(0) and 'data-vehicles-drawn="4"' in body.group(0)
    seq = re.search(r'id="last-seq">(\d+)<', dom)
    assert seq is not None and int(seq.group(1)) >= 41  # beyond the 40 epochs the page loaded first
    assert "v4 (offline)" in dom and "ready" in dom
    img = imread(shot)
    h, w = img.shape[:2]
    assert (w, h) == (1200, 800)
    plot = img[90:650, : int(0.52 * w)]  # the ENU canvas (left card), without the legend
    counts = {s: _pixels_near(plot, c) for s, c in PLANE_COLORS.items()}
    # every status is on some vehicle: a filled dot (~100 px) or, on the offline vehicle, a ring (~40 px)
    assert all(n >= 30 for n in counts.values()) and sum(counts.values()) >= 200, counts
    non_white = int(np.any(plot[..., :3] < 0.9, axis=-1).sum())
    assert non_white > 2000, non_white  # grid, trails, labels
    if os.environ.get("COPLANE_UPDATE_DOCS") == "1":
        (REPO / "docs" / "img").mkdir(parents=True, exist_ok=True)
        shutil.copyfile(shot, REPO / "docs" / "img" / "dashboard.png")
    print(
        f"\ndashboard: vehicle-colour pixels {counts}, non-white plot pixels {non_white}, last seq {seq.group(1)}"
    )


def test_dashboard_draws_the_road_map_tiles(tmp_path: Path) -> None:
    """With --map, the tiles of the view are drawn under the vehicles, coloured by sigma."""
    from support.api import ecef_at

    from coplane.roadmap import TilePlane, tile_of_ecef
    from coplane.store.roadmap_db import RoadMapDb

    keys = {
        tile_of_ecef(np.array(ecef_at(e, n)), 20.0)
        for e in range(-200, 201, 20)
        for n in range(-200, 201, 20)
    }
    info = np.diag([400.0, 30.0, 30.0])  # sigma about 0.07 m: the "<= 0.2 m" colour
    path = tmp_path / "map.sqlite"
    with RoadMapDb(path) as db:
        db.write(
            [
                TilePlane(key=k, h0_m=50.0, info=info, eta=np.zeros(3), n_passes=5, n_points=9, version=5)
                for k in keys
            ]
        )
    fleet = SyntheticFleet(n_vehicles=4, n_epochs=40)
    app = filled_app(fleet, epochs=40, map_path=path)
    shot = tmp_path / "dashboard.png"
    with serve(app) as url:
        cmd = [
            _chromium(), "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
            "--disable-background-networking", "--disable-component-update", "--disable-sync",
            "--hide-scrollbars", f"--user-data-dir={tmp_path / 'profile'}", f"--screenshot={shot}",
            "--window-size=1200,800", "--virtual-time-budget=3000", "--dump-dom", f"{url}/?events=1",
        ]  # fmt: skip
        out = subprocess.run(cmd, capture_output=True, text=True, timeout=90)
    assert out.returncode == 0, out.stderr[-2000:]
    drawn = re.search(r'data-tiles-drawn="(\d+)"', out.stdout)
    assert drawn is not None and int(drawn.group(1)) > 0, out.stdout[:500]
    plot = imread(shot)[90:650, :600]
    # the "<= 0.2 m" green at 55 % over white
    assert _pixels_near(plot, "#91c3a7", tol=0.1) > 1000
