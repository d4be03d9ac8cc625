"""Clean shutdown, multi-process: Ctrl-C or SIGTERM stops every process within 5 s, exit 130 / 143.

`coplane fleet --serve` runs in its own process group, as in a terminal: Ctrl-C there is SIGINT to
the whole group; `kill PID` is SIGTERM to the parent alone, which must stop its children itself.
Every service alone exits 130 on SIGINT and 143 on SIGTERM.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from support.e2e_fleet import signal_and_time, start_serving_fleet

from coplane.allocator import allocator_env
from coplane.fleet import free_port, wait_for_port
from coplane.sim.generate import simulate

pytestmark = [pytest.mark.slow, pytest.mark.serial]
LIMIT_S = 5.0  # the acceptance: every process gone within 5 s


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return simulate("urban-loop", tmp_path_factory.mktemp("rec") / "r", vehicles=2, duration_s=10, seed=5)


@pytest.mark.parametrize(
    ("sig", "group", "code"),
    [(signal.SIGINT, True, 130), (signal.SIGTERM, False, 143)],
    ids=["ctrl-c", "sigterm"],
)
def test_fleet_serve_stops_everything(
    recording: Path, tmp_path: Path, sig: int, group: bool, code: int
) -> None:
    p = start_serving_fleet(recording, tmp_path)
    time.sleep(0.5)
    t = signal_and_time(p, sig, group)
    print(f"{signal.Signals(sig).name} to {'the group' if group else 'the parent'}: {t}")
    assert t.n_processes >= 3  # router, fusion server, API (the agents are done when it serves)
    assert t.code == code
    assert not t.left, f"still running after {t.all_s:.1f} s: {t.left}"
    assert t.all_s < LIMIT_S and t.parent_s < LIMIT_S


def test_every_service_exits_128_plus_the_signal(recording: Path, tmp_path: Path) -> None:
    """Router, fusion server, agent and API, each signalled mid-run (the agent in realtime, so it
    is still replaying). They start on the allocator the launcher gives them, and the fusion server
    logs the one it found itself on."""
    port, api_port = free_port(), free_port()
    connect = f'["tcp/127.0.0.1:{port}"]'
    rec = str(recording)
    common = {"COPLANE_BUS_INSECURE": "1", **allocator_env()}
    cmds = {
        "router": ["coplane.bus.router", "--listen", f"tcp/127.0.0.1:{port}"],
        "fusion": [
            "coplane.fusion_server",
            "--recording",
            rec,
            "--connect",
            connect,
            "--pace",
            "realtime",
        ],
        "agent": [
            "coplane.vehicle_agent",
            "--recording",
            rec,
            "--vehicle_id",
            "u1",
            "--connect",
            connect,
            "--pace",
            "realtime",
        ],
        "api": ["coplane.api", "--recording", rec, "--connect", connect, "--port", str(api_port)],
    }
    logs = tmp_path / "logs"
    logs.mkdir()
    procs = {}
    for name, args in cmds.items():
        with (logs / f"{name}.log").open("wb") as out:
            procs[name] = subprocess.Popen(
                [sys.executable, "-m", *args], stdout=out, stderr=out, env={**os.environ, **common}
            )
    try:
        wait_for_port(api_port, timeout=120)
        wait_for_port(port, timeout=10)
        time.sleep(2.0)  # the fusion server and the agent are on the bus
        plan = {
            "agent": signal.SIGINT,
            "fusion": signal.SIGTERM,
            "api": signal.SIGINT,
            "router": signal.SIGTERM,
        }
        codes = {}
        for name, sig in plan.items():
            assert procs[name].poll() is None, (
                f"{name} ended early: {(logs / f'{name}.log').read_text()[-2000:]}"
            )
            t0 = time.monotonic()
            procs[name].send_signal(sig)
            codes[name] = procs[name].wait(LIMIT_S)
            assert time.monotonic() - t0 < LIMIT_S
        assert codes == {n: 128 + s for n, s in plan.items()}, codes
        lines = [json.loads(x) for x in (logs / "fusion.log").read_text().splitlines() if x.startswith("{")]
        found = [x.get("allocator") for x in lines if x.get("msg") == "memory allocator"]
        assert found == ["jemalloc" if allocator_env() else "system"], found
    finally:
        for p in procs.values():
            if p.poll() is None:
                p.kill()
                p.wait()


def test_a_process_that_ignores_sigterm_is_killed_and_logged(caplog: pytest.LogCaptureFixture) -> None:
    """The launcher's last resort (a router slow to stop on a loaded host): SIGKILL after the
    timeout, logged with the service's name. Its log record once named the service `process`, a
    LogRecord attribute, so the warning itself raised and the fleet's stop failed."""
    from coplane.fleet import FleetProcesses

    code = "import signal, time; signal.signal(signal.SIGTERM, signal.SIG_IGN); print('up', flush=True); time.sleep(60)"
    p = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE)
    assert p.stdout is not None and p.stdout.readline() == b"up\n"
    procs = FleetProcesses(procs={"stubborn": p})
    with caplog.at_level("WARNING", logger="coplane.fleet"):
        procs.stop_many(["stubborn"], 0.2)
    assert p.returncode == -signal.SIGKILL
    assert [r.__dict__.get("service") for r in caplog.records] == ["stubborn"]


def test_a_service_that_dies_before_listening_is_reported_at_once() -> None:
    """The launcher waits for the API to listen before the agents start; if it exits instead, the
    run stops with its exit code at once rather than after the whole wait."""
    from coplane.errors import CoplaneError

    proc = subprocess.Popen([sys.executable, "-c", "raise SystemExit(3)"])
    t0 = time.monotonic()
    with pytest.raises(CoplaneError, match="exited with code 3"):
        wait_for_port(free_port(), 30.0, proc)
    assert time.monotonic() - t0 < 10.0


def test_an_api_slow_to_listen_does_not_hold_the_replay(
    recording: Path, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """An API with a long solutions log to load listens late: after `api_start_timeout_s` the
    replay starts without it, says so, and still solves every epoch it solves in process (here the
    wait is 0 s, so the API cannot be listening yet)."""
    from coplane.evaluate.runner import run_method
    from coplane.fleet import FleetOptions, run_fleet
    from coplane.recording.reader import open_recording

    options = FleetOptions(
        recording=recording, api_port=free_port(), port=0, insecure=True, api_start_timeout_s=0.0
    )
    with caplog.at_level("WARNING", logger="coplane.fleet"):
        result = run_fleet(options)
    assert any("the API is not listening yet" in r.getMessage() for r in caplog.records)
    assert result.api_url is not None and not result.failed_agents and not result.interrupted
    in_process = run_method(open_recording(recording), "pc")
    assert {v: len(p) for v, p in result.run.positions.items()} == {
        v: len(p) for v, p in in_process.positions.items()
    }
