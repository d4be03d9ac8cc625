"""Issue 15 end to end: agents on live streams, with the fusion server and the collector as real
processes on a secure bus.

* lockstep through the live path: each agent reads its receiver log (`ubx+file://`), the base
  (`rtcm3+file://`) and UWB (`file://uwb.csv`) as streams; the positions equal the in-process
  replay of the same recording bit for bit;
* realtime on the wire: each vehicle's UBX comes over TCP at the recorded pace, the base from a
  real NTRIP caster (pygnssutils), UWB over UDP; positions equal the lockstep replay within the
  realtime pace's 1 mm (docs/reliability.md), the correction age is in every solution; the caster
  restarts and one receiver drops for 10 s mid-run: the client reconnects, the vehicle goes offline
  and comes back.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
from support.e2e_fleet import agents_done, live_fleet, wait_until

from coplane.bus.security import vehicle_identity
from coplane.evaluate.runner import run_method
from coplane.fleet.launcher import AGENT_MODULE, ServiceSpec
from coplane.recording.convert import convert_recording
from coplane.recording.reader import open_recording
from coplane.sim.generate import simulate

pytestmark = pytest.mark.slow
METHOD = "pc"


@pytest.fixture(scope="module")
def ubx_recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """urban-loop, 3 vehicles, 30 s, with a base and UWB, converted to UBX (+ RTCM 3 base)."""
    root = tmp_path_factory.mktemp("live-fleet")
    simulate("urban-loop", root / "sim", 3, 30, seed=3)
    convert_recording(root / "sim", "ubx", root / "ubx")
    return root / "ubx"


def agent_spec(
    rec: Path, vid: str, connect: str, pace: str, gnss: str, base: str | None, uwb: str | None
) -> ServiceSpec:
    args = ["--recording", str(rec), "--vehicle_id", vid, "--method", METHOD, "--pace", pace]
    args += ["--connect", f'["{connect}"]', "--gnss", gnss]
    args += ["--base", base] if base else []
    args += ["--uwb", uwb] if uwb else []
    return ServiceSpec(f"agent-{vid}", AGENT_MODULE, args, vehicle_identity(vid))


def test_lockstep_through_the_live_path_equals_the_replay(ubx_recording: Path, tmp_path: Path) -> None:
    rec = open_recording(ubx_recording)
    man = rec.manifest
    assert man.base is not None and man.uwb is not None
    ref = run_method(rec, METHOD)
    ages: list[float | None] = []
    listen = [lambda sol: ages.extend(s.dgnss_age_s for s in sol.vehicles)]
    with live_fleet(ubx_recording, METHOD, log_dir=tmp_path / "logs", agents=[], listeners=listen) as lf:
        for v in man.vehicles:
            lf.procs.start(
                agent_spec(
                    ubx_recording,
                    v.id,
                    lf.connect,
                    "lockstep",
                    f"ubx+file://{v.obs}",
                    f"rtcm3+file://{man.base.obs}",
                    f"file://{man.uwb.file}",
                )
            )
        wait_until(lambda: agents_done(lf.procs), 240, "agents to finish")
        time.sleep(0.5)
        bus = {v: dict(p) for v, p in lf.collector.run.positions.items()}
    for v in man.vehicles:  # the agents ran on the streams, not on the recording's files
        log = (tmp_path / "logs" / f"agent-{v.id}.log").read_text()
        assert "agent started on live streams" in log and '"epochs": 30' in log, log[-2000:]
    for vid, pos in ref.positions.items():
        assert set(pos) == set(bus[vid]), vid
        for t, p in pos.items():
            assert np.array_equal(p, bus[vid][t]), (vid, t)
    # DGNSS from the base stream on every epoch with a fix, corrections of the same epoch
    assert ages and all(a is not None and abs(a) < 0.01 for a in ages)
