"""NMEA 0183 output (issue 15): an NMEA client (pynmeagps' reader) on each vehicle's port receives a
valid GGA, GST and RMC for every vehicle and epoch, checksums correct, positions equal to the
solution at NMEA precision."""

from __future__ import annotations

import math
import socket
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from pynmeagps import NMEAReader
from support.e2e_fleet import agents_done, live_fleet, wait_until

from coplane.fleet import fleet_of
from coplane.geo import ecef_to_geodetic, enu_rotation
from coplane.gtime import gpst_to_utc
from coplane.live.nmea_out import NmeaServer
from coplane.sim.generate import simulate

pytestmark = pytest.mark.slow


def _read_all(port: int, out: list) -> None:
    """Read sentences until the server closes the connection (checksums checked, errors raise)."""
    with socket.create_connection(("127.0.0.1", port)) as s:
        reader = NMEAReader(s.makefile("rb"), validate=1, quitonerror=2)
        while True:
            raw, msg = reader.read()
            if raw is None:
                return
            out.append(msg)


def test_every_vehicle_gets_gga_and_rmc_for_every_epoch(tmp_path: Path) -> None:
    rec = simulate("urban-loop", tmp_path / "r", vehicles=3, duration_s=20, seed=4)
    _, vehicles = fleet_of(rec)
    server = NmeaServer(vehicles, 0)
    got: dict[str, list] = {v: [] for v in vehicles}
    readers = [
        threading.Thread(target=_read_all, args=(server.ports[v], got[v]), daemon=True) for v in vehicles
    ]
    for r in readers:
        r.start()
    wait_until(lambda: server.counts["connections"] == len(vehicles), 10, "the NMEA clients")
    try:
        with live_fleet(rec, "pc", log_dir=tmp_path / "logs", secure=False, listeners=[server.publish]) as lf:
            wait_until(lambda: agents_done(lf.procs), 240, "agents to finish")
            time.sleep(1.0)
            positions = {v: dict(p) for v, p in lf.collector.run.positions.items()}
            covariances = {v: dict(c) for v, c in lf.collector.run.covariances.items()}
    finally:
        server.close()  # the clients see the end of their streams
    for r in readers:
        r.join(10)
    for vid in vehicles:
        gga = [m for m in got[vid] if m.msgID == "GGA"]
        rmc = [m for m in got[vid] if m.msgID == "RMC"]
        sol = positions[vid]
        assert len(gga) == len(rmc) == len(sol) >= 19, (vid, len(gga), len(rmc), len(sol))
        for m, (t, p) in zip(gga, sorted(sol.items()), strict=True):
            utc = gpst_to_utc(t)
            assert m.time == utc.time()
            lat, lon, h = ecef_to_geodetic(np.asarray(p))
            # 7 decimals of minutes: 1/6e8 deg, about 0.2 mm
            assert abs(m.lat - math.degrees(lat)) < 2e-9 and abs(m.lon - math.degrees(lon)) < 2e-9
            assert abs(m.alt - h) <= 5e-4 and m.quality in (2, 6)
            # the agent's fix: its HDOP and corrections' age, empty where its SPP gave none
            assert m.HDOP == "" or (0.0 < m.HDOP < 50.0 and 0.0 <= m.diffAge < 60.0), (m.HDOP, m.diffAge)
        assert sum(m.HDOP != "" for m in gga) > len(gga) // 2
        # the covariance as GST: 1-sigma north / east / up and the horizontal ellipse
        gst = [m for m in got[vid] if m.msgID == "GST"]
        assert len(gst) == len(sol)
        for m, t in zip(gst, sorted(sol), strict=True):
            lat, lon, _ = ecef_to_geodetic(np.asarray(sol[t]))
            r = enu_rotation(lat, lon)
            enu = r @ covariances[vid][t] @ r.T
            assert m.time == gpst_to_utc(t).time()
            assert (m.stdLat, m.stdLong, m.stdAlt) == pytest.approx(
                np.sqrt(np.diag(enu))[[1, 0, 2]], abs=6e-4
            )
            assert m.stdMajor**2 + m.stdMinor**2 == pytest.approx(enu[0, 0] + enu[1, 1], rel=1e-2)
            assert m.stdMinor <= m.stdMajor and 0.0 <= m.orient < 180.0
        assert all(r.status in ("A", "V") and r.date == gpst_to_utc(min(sol)).date() for r in rmc)


def test_an_agent_serves_its_own_vehicle_as_nmea(tmp_path: Path) -> None:
    """`coplane agent --nmea-port P`: the car's other systems read its fused position from its own
    agent, GGA + GST + RMC, at the positions the fleet solved (the epochs after the client
    connected)."""
    from coplane.fleet.launcher import free_port

    rec = simulate("urban-loop", tmp_path / "r", vehicles=2, duration_s=20, seed=4)
    port, got = free_port(), []
    with live_fleet(
        rec, "pc", log_dir=tmp_path / "logs", secure=False, agent_args={"u1": ["--nmea_port", str(port)]}
    ) as lf:
        wait_until(lambda: _connectable(port), 30, "the agent's NMEA port")
        reader = threading.Thread(target=_read_all, args=(port, got), daemon=True)
        reader.start()
        wait_until(lambda: agents_done(lf.procs), 240, "agents to finish")
        reader.join(15)  # the agent closes its NMEA server when it finishes
        positions = dict(lf.collector.run.positions["u1"])
    gga = [m for m in got if m.msgID == "GGA"]
    assert len(gga) >= 10 and len([m for m in got if m.msgID == "GST"]) == len(gga)
    by_time = {gpst_to_utc(t).time(): p for t, p in positions.items()}
    for m in gga:
        lat, lon, _ = ecef_to_geodetic(np.asarray(by_time[m.time]))
        assert abs(m.lat - math.degrees(lat)) < 2e-9 and abs(m.lon - math.degrees(lon)) < 2e-9


def _connectable(port: int) -> bool:
    try:
        socket.create_connection(("127.0.0.1", port), timeout=1).close()
        return True
    except OSError:
        return False


def test_a_taken_port_is_a_clear_error() -> None:
    """`--nmea-port` on a port another program holds: a ConfigError naming it, not a traceback."""
    from coplane.errors import ConfigError

    with socket.create_server(("127.0.0.1", 0)) as taken:
        port = taken.getsockname()[1]
        with pytest.raises(ConfigError, match=f"NMEA output for u1: cannot listen on 127.0.0.1:{port} "):
            NmeaServer(["u1"], port)


def test_ports_past_65535_are_a_clear_error() -> None:
    """The vehicles take the ports from --nmea-port on: the last one must exist too (an
    OverflowError from bind() before)."""
    from coplane.errors import ConfigError

    with pytest.raises(
        ConfigError, match=r"ports 65535\.\.65536 for 2 vehicle\(s\) are not all within 1\.\.65535"
    ):
        NmeaServer(["u1", "u2"], 65535)
    with pytest.raises(ConfigError, match=r"ports -5\.\.-5 for 1 vehicle"):
        NmeaServer(["u1"], -5)
