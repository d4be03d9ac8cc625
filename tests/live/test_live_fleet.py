"""Issue 15 end to end: agents on live streams, with the fusion server and the collector as real
processes on a secure bus.

* lockstep through the live path: each agent reads its receiver log (`ubx+file://`), the base
  (`rtcm3+file://`) and UWB (`file://uwb.csv`) as streams; the positions equal the in-process
  replay of the same recording bit for bit;
* realtime on the wire: each vehicle's UBX comes over TCP at the recorded pace, the base from a
  real NTRIP caster (pygnssutils' server in NTRIP mode, its own process), UWB over UDP; positions equal the lockstep replay within the
  realtime pace's 1 mm (docs/reliability.md), the correction age is in every solution; the caster
  restarts and one receiver drops for 10 s mid-run: the client reconnects, the vehicle goes offline
  and comes back.
"""

from __future__ import annotations

import json
import shutil
import socket
import threading
import time
import urllib.request
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from support.e2e_fleet import agents_done, live_fleet, wait_until
from support.ntrip_caster import MOUNTPOINT, start_caster
from support.receiver import PacedReceiver

from coplane.bus.security import API, vehicle_identity
from coplane.evaluate.runner import run_method
from coplane.fleet.launcher import AGENT_MODULE, API_MODULE, ServiceSpec, free_port
from coplane.gtime import GpsTime
from coplane.recording.convert import convert_recording
from coplane.recording.reader import open_recording
from coplane.recording.ubx import write_ubx
from coplane.sim.generate import simulate

pytestmark = pytest.mark.slow
METHOD = "pc"


@pytest.fixture(scope="module")
def ubx_recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """urban-loop, 3 vehicles, 45 s, with a base and UWB, converted to UBX (+ RTCM 3 base)."""
    root = tmp_path_factory.mktemp("live-fleet")
    simulate("urban-loop", root / "sim", 3, 45, seed=3)
    convert_recording(root / "sim", "ubx", root / "ubx")
    return root / "ubx"


def free_port_udp() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


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
        assert "agent started on live streams" in log and '"epochs": 45' in log, log[-2000:]
    for vid, pos in ref.positions.items():
        assert set(pos) == set(bus[vid]), vid
        for t, p in pos.items():
            assert np.array_equal(p, bus[vid][t]), (vid, t)
    # DGNSS from the base stream on every epoch with a fix, corrections of the same epoch
    assert ages and all(a is not None and abs(a) < 0.01 for a in ages)


class UwbSender:
    """uwb.csv sent as UDP lines at the recorded pace to each agent's port (every line to every
    agent: each keeps its own ranges), with a garbage line between the epochs."""

    def __init__(self, path: Path, ports: list[int], start_unix_s: float, t0: GpsTime) -> None:
        rows = [r for r in path.read_text().splitlines()[1:] if r.strip()]
        self.by_time: dict[float, list[str]] = {}
        for r in rows:
            week, tow = r.split(",")[:2]
            self.by_time.setdefault(GpsTime(int(week), float(tow)) - t0, []).append(r)
        self.ports, self.start = ports, start_unix_s
        self.stop = threading.Event()
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        for dt in sorted(self.by_time):
            due = self.start + dt
            if due < time.time() - 0.5:
                continue
            if self.stop.wait(max(0.0, due - time.time())):
                return
            data = ("\n".join(self.by_time[dt]) + "\nnot,a,range\n").encode()
            for port in self.ports:
                self.sock.sendto(data, ("127.0.0.1", port))

    def close(self) -> None:
        self.stop.set()
        self.thread.join(3.0)
        self.sock.close()


def _get(url: str) -> Any:
    with urllib.request.urlopen(url, timeout=5) as r:
        return json.loads(r.read()) if "json" in r.headers.get("content-type", "") else r.read().decode()


def _same_epoch(age: float | None) -> bool:
    """Corrections of the rover's own epoch (the age is then the receivers' clock offsets, ms)."""
    return age is not None and abs(age) < 0.1


REALTIME_TOL_M = 1e-3  # docs/reliability.md: realtime against the lockstep replay
# The server's realtime deadline here: an agent's first epochs (cold caches) can take longer than
# the default 0.5 s on a slow host, and an epoch solved without a vehicle changes the window of every
# later one. The test is about streams and faults, not about the deadline.
DEADLINE_S = 1.5


BASE_LEAD_EPOCHS = 2


@pytest.fixture(scope="module")
def late_vehicles(ubx_recording: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The UBX recording with the vehicles starting BASE_LEAD_EPOCHS after the base. An agent
    drops the first base epoch after joining a stream (it may lack MSMs sent before), and
    pygnssutils' caster does mangle the first epoch it relays to a client (measured: GPS MSM lost,
    BeiDou MSM twice): with the base ahead, the vehicles' first epoch has its corrections, as in
    the replay."""
    out = tmp_path_factory.mktemp("late") / "rec"
    shutil.copytree(ubx_recording, out)
    rec = open_recording(out)
    for v in rec.manifest.vehicles:
        write_ubx(v.obs, rec.vehicle_epochs(v.id)[BASE_LEAD_EPOCHS:], nav=rec.nav)
    return out


@pytest.mark.serial
def test_realtime_streams_with_a_caster_restart_and_a_receiver_drop(
    late_vehicles: Path, tmp_path: Path
) -> None:
    ubx_recording = late_vehicles
    rec = open_recording(ubx_recording)
    man = rec.manifest
    assert man.base is not None and man.uwb is not None
    ref = run_method(rec, METHOD)
    t0 = rec.base_epochs()[0].time.round_to(man.interval_s)  # the recording's clock: the base's
    # agents, server and API start meanwhile; every agent must be on the caster before the base's
    # last lead epoch (it drops the first it gets). With 8 s, twice on a loaded 2-core AVX2 host:
    # epoch 0 left out of the comparison (all three vehicles there), then 0.2-1.1 m off the replay
    # from epoch 1 on, the same figures both times, as if epoch 0 had no same-epoch correction (not
    # confirmed: the ages were not printed then; they are now)
    start = time.time() + 15.0
    receivers = {v.id: PacedReceiver(v.obs, "ubx", start, t0) for v in man.vehicles}
    caster_port = free_port()
    caster = start_caster(man.base.obs, caster_port, "base", "pw-s3cret", start, t0)
    uwb_ports = {v.id: free_port_udp() for v in man.vehicles}
    uwb = UwbSender(man.uwb.file, list(uwb_ports.values()), start, t0)
    api_port = free_port()
    solutions: list = []
    seen_ages: list[tuple[float, float | None, str]] = []
    seen_online: list[tuple[float, str, bool]] = []
    try:
        with live_fleet(
            ubx_recording, METHOD, pace="realtime", log_dir=tmp_path / "logs", agents=[],
            listeners=[solutions.append], extra_fusion_args=["--deadline_s", str(DEADLINE_S)],
        ) as lf:  # fmt: skip
            lf.procs.start(
                ServiceSpec(
                    "api",
                    API_MODULE,
                    [
                        "--recording",
                        str(ubx_recording),
                        "--connect",
                        f'["{lf.connect}"]',
                        "--port",
                        str(api_port),
                    ],
                    API,
                )
            )
            for v in man.vehicles:
                lf.procs.start(
                    agent_spec(
                        ubx_recording,
                        v.id,
                        lf.connect,
                        "realtime",
                        f"ubx+tcp://127.0.0.1:{receivers[v.id].port}",
                        f"ntrip://base:pw-s3cret@127.0.0.1:{caster_port}/{MOUNTPOINT}",
                        f"udp://127.0.0.1:{uwb_ports[v.id]}",
                    )
                )
            # faults, on the recording's clock: the caster goes down at 12 s and restarts at 18 s,
            # u3's receiver drops for 10 s at 18 s
            time.sleep(max(0.0, start + 12.0 - time.time()))
            caster.kill()
            caster.wait()
            time.sleep(max(0.0, start + 18.0 - time.time()))
            caster = start_caster(man.base.obs, caster_port, "base", "pw-s3cret", start, t0)
            receivers["u3"].drop(10.0)
            while time.time() < start + 44.0:  # the API shows the correction age, who is online
                try:
                    vs = _get(f"http://127.0.0.1:{api_port}/vehicles")["vehicles"]
                    now = time.time() - start
                    seen_ages += [(now, v.get("dgnss_age_s"), v["vehicle_id"]) for v in vs]
                    seen_online += [(now, v["vehicle_id"], v["online"]) for v in vs]
                except OSError:
                    pass
                time.sleep(0.5)
            metrics = _get(f"http://127.0.0.1:{api_port}/metrics")
            wait_until(lambda: time.time() > start + 46, 60, "the recording's end")
            time.sleep(1.0)
    finally:
        for r in receivers.values():
            r.close()
        caster.kill()
        caster.wait()
        uwb.close()
    by_epoch = {sol.epoch.tow: {s.vehicle_id: s for s in sol.vehicles} for sol in solutions}
    tows = sorted(by_epoch)
    assert tows, "no solution"
    first = tows[0]
    print(
        "first epochs:",
        [(tw - first, {v: s.dgnss_age_s for v, s in by_epoch[tw].items()}) for tw in tows[:4]],
    )
    # 1. clean epochs (before the faults, all three vehicles, same-epoch corrections, and each
    # vehicle with the replay's number of ranges: a UWB datagram that missed its epoch's
    # alignment window changes the inputs, not the estimator): the replay's
    week = int(solutions[0].epoch.week)

    def same_ranges(tw: float) -> bool:
        t = GpsTime(week, tw)
        return all(s.n_ranges == ref.ranges_used[vid].get(t) for vid, s in by_epoch[tw].items())

    clean = [
        tw for tw in tows
        if tw - first < 9 and len(by_epoch[tw]) == 3 and all(_same_epoch(s.dgnss_age_s) for s in by_epoch[tw].values())
        and same_ranges(tw)
    ]  # fmt: skip
    assert len(clean) >= 5, [(tw, {v: s.dgnss_age_s for v, s in by_epoch[tw].items()}) for tw in tows[:15]]
    worst = 0.0
    for tw in clean:
        for vid, s in by_epoch[tw].items():
            t = GpsTime(int(solutions[0].epoch.week), tw)
            d = float(np.linalg.norm(np.asarray(s.position_ecef_m) - ref.positions[vid][t]))
            if d > REALTIME_TOL_M:
                print(
                    f"epoch {tw - first:.0f} {vid}: {d:.4f} m, age {s.dgnss_age_s} npr {s.n_pseudoranges} nr {s.n_ranges} plane {s.plane_status}"
                )
            worst = max(worst, d)
    print(f"realtime live streams vs lockstep replay: max {worst * 1e3:.3f} mm over {len(clean)} epochs")
    assert worst <= REALTIME_TOL_M
    # 2. the caster outage: the age grows in the solutions and in the API, then the feed is back
    ages = [s.dgnss_age_s for tw in tows for s in by_epoch[tw].values() if s.dgnss_age_s is not None]
    assert max(ages) >= 3.0, ages
    assert any(a is not None and a >= 3.0 for _, a, _ in seen_ages), seen_ages
    assert "coplane_vehicle_dgnss_age_seconds" in metrics
    late = [tw for tw in tows if tw - first > 26 and "u1" in by_epoch[tw]]
    assert late and _same_epoch(by_epoch[late[-1]]["u1"].dgnss_age_s)  # reconnected: same-epoch corrections
    # 3. u3's receiver drop: the vehicle goes offline (its agent withdraws its token, so the fleet
    # does not wait for it) and comes back with its receiver
    u3 = [(t, online) for t, vid, online in seen_online if vid == "u3"]
    assert any(not online for t, online in u3 if 20 < t < 29), u3
    assert any(online for t, online in u3 if t > 32), u3
    assert all(online for t, vid, online in seen_online if vid != "u3" and 10 < t < 40)
    after = [sol.epoch.tow - first for sol in solutions if "u3" in by_epoch[sol.epoch.tow]]
    print(f"u3 in solutions at epochs {after}")
    assert any(x > 31 for x in after), after
    log = (tmp_path / "logs" / "agent-u1.log").read_text()
    assert "connection closed by the caster" in log and "ntrip corrections flowing" in log
    assert "pw-s3cret" not in log
    log = (tmp_path / "logs" / "agent-u3.log").read_text()
    assert "live source down, retrying" in log and "receiver silent: vehicle offline" in log
    assert "receiver back: vehicle online" in log
