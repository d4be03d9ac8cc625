"""kill -9 of the fusion server and then of the API in a live realtime fleet (issue 13 acceptance).

The full measurement, with more kill points and both paces, is bench/reliability_durability.py.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from support.durability_fleet import kill_and_restart

from coplane.sim.generate import simulate

pytestmark = [pytest.mark.slow, pytest.mark.serial]


def test_kill_9_loses_nothing_published_and_keeps_the_api_tracks(tmp_path: Path) -> None:
    rec = simulate("urban-loop", tmp_path / "rec", vehicles=3, duration_s=30, seed=5)
    r = kill_and_restart(
        rec,
        tmp_path / "run",
        ["fusion-server", "api"],
        speed=2.0,
        kill_after=8,
        kill_gap=8,
        start_delay_s=10.0,
    )
    print(r)
    assert not r.notes, r.notes
    assert r.resumed  # the restarted server took over from its log
    assert r.published_not_logged == 0  # committed before published
    assert r.duplicate_epochs == 0  # no epoch solved twice
    assert r.missed_epochs <= 2
    assert r.api_tracks_equal  # the API's history came back
