"""Two Zenoh routers in a mesh (issue 16, operations): `coplane fleet --routers 2` on the secure
bus. The servers and agents take the routers in turn, so node messages and solutions cross the
router-to-router link (mutual TLS with the routers' own certificate, each router's ACL granting
the other everything under the fleet's prefix). Lockstep over the mesh equals the in-process
replay bit for bit, with one server and with two by region; the access control still holds for a
vehicle on the second router."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import zenoh

from coplane.bus import BusSecurity, router_config
from coplane.bus.certs import init_certs
from coplane.bus.probe import client_config
from coplane.evaluate.runner import run_method
from coplane.fleet import FleetOptions, free_port, run_fleet
from coplane.recording.reader import open_recording
from coplane.sim.generate import run_simulation, write_recording

pytestmark = pytest.mark.slow


@pytest.mark.parametrize("servers", [1, 2])
def test_lockstep_over_two_routers_equals_the_replay(tmp_path: Path, servers: int) -> None:
    rec_path = write_recording(run_simulation("urban-loop", 4, 20.0, 8), tmp_path / "r")
    ref = run_method(open_recording(rec_path), "pc")
    res = run_fleet(
        FleetOptions(
            recording=rec_path,
            api=False,
            certs=tmp_path / "certs",
            map=Path("none"),
            servers=servers,
            routers=2,
            port=0,
            logs=tmp_path / "logs",
        )
    )
    assert (tmp_path / "logs" / "zenoh-router-2.log").exists()
    for vid, pos in ref.positions.items():
        assert set(pos) == set(res.run.positions[vid]), vid
        for t, p in pos.items():
            assert np.array_equal(p, res.run.positions[vid][t]), (vid, t)


def test_the_second_router_applies_the_access_control(tmp_path: Path) -> None:
    certs = tmp_path / "certs"
    init_certs(certs, ["u1", "u2"])
    sec = BusSecurity(certs=certs)
    a, b = f"tls/127.0.0.1:{free_port()}", f"tls/127.0.0.1:{free_port()}"
    ra = zenoh.open(router_config([a], sec, fleet="f1"))
    rb = zenoh.open(router_config([b], sec, fleet="f1", connect=[a]))
    fusion = zenoh.open(client_config(a, sec.as_identity("fusion")))
    monitor = zenoh.open(client_config(a, sec.as_identity("monitor")))
    vehicle = zenoh.open(client_config(b, sec.as_identity("vehicle-u1")))
    solution = json.dumps({"k": 1}).encode()
    try:
        nodes: list[bytes] = []
        seen: list[bytes] = []  # solutions the monitor on the first router receives
        got: list[bytes] = []  # solutions the vehicle on the second router receives
        fusion.declare_subscriber("coplane/v1/f1/vehicle/*/node", lambda s: nodes.append(bytes(s.payload)))
        monitor.declare_subscriber("coplane/v1/f1/solution", lambda s: seen.append(bytes(s.payload)))
        vehicle.declare_subscriber("coplane/v1/f1/solution", lambda s: got.append(bytes(s.payload)))
        deadline = time.monotonic() + 10.0
        while not (nodes and seen and solution in got) and time.monotonic() < deadline:
            vehicle.put("coplane/v1/f1/vehicle/u1/node", b"own")
            vehicle.put("coplane/v1/f1/vehicle/u2/node", b"forged")  # another vehicle's key
            vehicle.put("coplane/v1/f1/solution", b"forged")  # the server's key
            fusion.put("coplane/v1/f1/solution", solution)
            time.sleep(0.2)
        time.sleep(0.5)
        assert nodes and set(nodes) == {b"own"}  # across the mesh, and only its own key
        assert seen and set(seen) == {solution}  # the vehicle's forged solution stopped at its router
        assert solution in got  # the server's solution crossed the mesh to the vehicle
    finally:
        for s in (vehicle, monitor, fusion, rb, ra):
            s.close()


def test_a_malformed_mesh_endpoint_is_a_clear_error() -> None:
    """`python -m coplane.bus.router --connect garbage`: one error line naming the endpoints, exit 2."""
    out = subprocess.run(
        [sys.executable, "-m", "coplane.bus.router", "--listen", f"tcp/127.0.0.1:{free_port()}",
         "--connect", "garbage"],
        capture_output=True, text=True, timeout=30, env={**os.environ, "COPLANE_BUS_INSECURE": "1"},
    )  # fmt: skip
    assert out.returncode == 2
    assert "router could not start" in out.stderr + out.stdout and "garbage" in out.stderr + out.stdout
    assert "Traceback" not in out.stderr
