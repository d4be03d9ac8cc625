"""`coplane loadgen` (issue 16): every vehicle of a recording as its own VehicleStep on one bus
session gives the same solutions as one agent process per vehicle (the in-process replay), with one
and with several servers; and it refuses a secure bus."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from support.e2e_fleet import wait_until
from typer.testing import CliRunner

from coplane.bus import BusSecurity, use_security
from coplane.cli import app
from coplane.evaluate.runner import run_method
from coplane.fleet import (
    Collector,
    FleetProcesses,
    fleet_of,
    fleet_services,
    free_port,
    router_spec,
    wait_for_port,
)
from coplane.recording.reader import open_recording
from coplane.sim.generate import run_simulation, write_recording
from coplane.vehicle_agent.loadgen import LoadGenerator
from coplane.vehicle_agent.settings import LoadgenSettings

pytestmark = pytest.mark.slow


@pytest.mark.parametrize("servers", [1, 2])
def test_loadgen_equals_the_in_process_replay(tmp_path: Path, servers: int) -> None:
    rec_path = write_recording(run_simulation("city", 12, 20.0, 3), tmp_path / "r")
    ref = run_method(open_recording(rec_path), "pc")
    fleet, vehicles = fleet_of(rec_path)
    port = free_port()
    connect = f"tcp/127.0.0.1:{port}"
    region = ["--region_size_m", "600", "--region_margin_m", "250"]
    with use_security(BusSecurity(insecure=True)):
        procs = FleetProcesses(log_dir=tmp_path / "logs", security=BusSecurity(insecure=True))
        try:
            procs.start(router_spec(port))
            wait_for_port(port)
            for spec in fleet_services(rec_path, "pc", "lockstep", 1.0, connect, [], False, servers=servers):
                if spec.name.startswith("fusion-server"):
                    spec.args += ["--db", "none", *(region if servers > 1 else [])]
                    procs.start(spec)
            with Collector(fleet, "pc", connect, vehicles=vehicles) as c:
                settings = LoadgenSettings(
                    recording=rec_path,
                    connect=[connect],
                    regions=servers > 1,
                    region_size_m=600.0,
                    region_margin_m=250.0,
                )
                gen = LoadGenerator(settings)
                stats = gen.run()
                wait_until(
                    lambda: c.epochs > 0 and all(len(p) == 20 for p in c.run.positions.values()), 10, "all"
                )
                got = {v: dict(p) for v, p in c.run.positions.items()}
        finally:
            procs.stop_all()
    assert stats.published == 12 * 20 and stats.unanswered == 0
    assert stats.await_ends == {"answered": 20} and not stats.unanswered_by_epoch
    # lockstep timed every epoch's answer: the re-send timeout is learnt, never below the setting
    assert gen.resend.srtt_s is not None and gen.resend.timeout_s() >= settings.resend_s
    if servers == 1:  # one server: the in-process replay, bit for bit
        for vid, pos in ref.positions.items():
            for t, p in pos.items():
                assert np.array_equal(p, got[vid][t]), (vid, t)
    else:  # by region: every epoch solved, hand-overs within the documented tolerance
        d = [np.linalg.norm(p - got[v][t]) for v, pos in ref.positions.items() for t, p in pos.items()]
        assert np.median(d) < 0.01 and max(d) < 3.0


def test_loadgen_refuses_a_secure_bus() -> None:
    out = CliRunner().invoke(app, ["loadgen"])
    assert out.exit_code != 0 and "--insecure" in out.output


def test_realtime_counts_vehicle_epochs_without_an_answer() -> None:
    """Realtime: nobody waits, so a vehicle-epoch no solution answered is unanswered, not solved;
    lockstep counts what it gave up on."""
    from coplane.vehicle_agent.loadgen import LoadStats

    rt = LoadStats(vehicles=2, published=10, answered=9, answered_once=7, pace="realtime").summary()
    assert (rt["solved"], rt["unanswered"], rt["extra_answers"]) == (7, 3, 2)
    ls = LoadStats(vehicles=2, published=10, answered=10, answered_once=9, unanswered=1).summary()
    assert (ls["solved"], ls["unanswered"]) == (9, 1)
    where = LoadStats(unanswered=3, await_ends=Counter(answered=4, timeout=1), unanswered_by_epoch={2: 3})
    assert (where.summary()["await_ends"], where.summary()["unanswered_by_epoch"]) == (
        {"answered": 4, "timeout": 1},
        {"2": 3},
    )
