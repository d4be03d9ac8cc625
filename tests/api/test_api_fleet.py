"""The API against a running fleet: router, fusion server, agents and API as separate processes.

One lockstep replay of a small simulated 3-vehicle recording; during it a Zenoh client injects
malformed node messages (and malformed solutions). Afterwards every endpoint is compared with what
a test-side subscriber saw on the solution key (the same data `coplane fleet --out` writes as
CSV), the metrics with the injected counts, and finally the API's readiness is followed while the
fusion server and then the router are killed and restarted.
"""

from __future__ import annotations

import csv
import json
import math
import signal
import threading
import time
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
import zenoh
from prometheus_client.parser import text_string_to_metric_families

from coplane.bus import KeySpace, decode, payload_bytes, session_config
from coplane.evaluate.report import run_stats, write_solutions
from coplane.evaluate.runner import MethodRun, record_solution
from coplane.fleet import (
    FleetProcesses,
    ServiceSpec,
    fleet_of,
    fleet_services,
    free_port,
    router_spec,
    wait_for_port,
)
from coplane.geo import ecef_to_geodetic
from coplane.messages import SolutionMessage, plane_source
from coplane.recording.reader import open_recording

pytestmark = pytest.mark.slow
METHOD = "pc"
BAD_JSON = 5  # to vehicle 1's node key
BAD_MODEL = 3  # to vehicle 2's node key
UNKNOWN = 2  # to a vehicle the recording does not have
BAD_SOLUTIONS = 4  # to the solution key (the API, the agents and the recorder must shrug them off)


@dataclass
class Run:
    rec: Path
    fleet: str
    vehicles: list[str]
    url: str
    procs: FleetProcesses
    specs: dict[str, ServiceSpec]
    connect: str
    router_port: int
    solutions: list[SolutionMessage] = field(default_factory=list)
    csv_dir: Path | None = None
    timings: dict[str, float] = field(default_factory=dict)

    def get(self, path: str, **params: Any) -> httpx.Response:
        return httpx.get(self.url + path, params=params, timeout=10)


def _wait(pred: Any, timeout: float, what: str) -> float:
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        if pred():
            return time.monotonic() - t0
        time.sleep(0.05)
    raise AssertionError(f"timed out after {timeout} s waiting for {what}")


def _ready(run: Run) -> bool:
    try:
        return run.get("/readyz").status_code == 200
    except httpx.HTTPError:
        return False


def _metrics(text: str) -> dict[tuple[str, tuple[tuple[str, str], ...]], float]:
    return {
        (s.name, tuple(sorted(s.labels.items()))): s.value
        for fam in text_string_to_metric_families(text)
        for s in fam.samples
    }


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Run]:
    from coplane.sim.generate import simulate

    tmp = tmp_path_factory.mktemp("apifleet")
    rec = simulate(out_dir=tmp / "rec", vehicles=3, duration_s=40, seed=7)
    fleet, vehicles = fleet_of(rec)
    rport, aport = free_port(), free_port()
    connect = f"tcp/127.0.0.1:{rport}"
    specs = {s.name: s for s in fleet_services(rec, METHOD, "lockstep", 1.0, connect, vehicles, True, aport)}
    specs["zenoh-router"] = router_spec(rport)
    procs = FleetProcesses(log_dir=tmp / "logs")
    r = Run(rec, fleet, vehicles, f"http://127.0.0.1:{aport}", procs, specs, connect, rport)
    keys = KeySpace(fleet)
    lock = threading.Lock()

    def on_solution(sample: Any) -> None:
        try:
            sol = decode(SolutionMessage, payload_bytes(sample))
        except Exception:
            return  # the injected garbage
        with lock:
            r.solutions.append(sol)

    session = None
    try:
        procs.start(specs["zenoh-router"])
        wait_for_port(rport)
        procs.start(specs["api"])  # first, with the exact flags the launcher gives it
        wait_for_port(aport, 30)
        ready = r.get("/readyz")
        assert ready.status_code == 503 and "no solution received yet" in ready.json()["reasons"]
        session = zenoh.open(session_config("client", [connect]))
        session.declare_subscriber(keys.solution, on_solution)
        procs.start(specs["fusion-server"])
        for v in vehicles:
            procs.start(specs[f"agent-{v}"])
        t0 = time.monotonic()
        _wait(lambda: len(r.solutions) >= 3, 60, "the first solutions")
        for _ in range(BAD_JSON):
            session.put(keys.node(vehicles[0]), b"{not json")
        bad_model = json.dumps({"schema": "coplane.node/1", "fleet": fleet, "vehicle_id": vehicles[1]})
        for _ in range(BAD_MODEL):
            session.put(keys.node(vehicles[1]), bad_model.encode())
        for _ in range(UNKNOWN):
            session.put(keys.node("ghost"), b"{}")
        for _ in range(BAD_SOLUTIONS):
            session.put(keys.solution, b"\x00garbage")
        agents = [procs.procs[f"agent-{v}"] for v in vehicles]
        _wait(lambda: all(p.poll() is not None for p in agents), 120, "the agents to finish")
        r.timings["replay_s"] = time.monotonic() - t0
        assert all(p.returncode == 0 for p in agents), [p.returncode for p in agents]
        time.sleep(1.6)  # one more diagnostics period of the fusion server
        run_ = MethodRun(METHOD, 0.0)
        for sol in r.solutions:
            record_solution(run_, sol, {})
        write_solutions(run_, tmp / "out")  # the files `coplane fleet --out` writes
        r.csv_dir = tmp / "out" / "solutions" / METHOD
        yield r
    finally:
        if session is not None:
            session.close()
        procs.stop_all()


def _csv_rows(path: Path) -> list[dict[str, str]]:
    with path.open() as fh:
        return list(csv.DictReader(fh))


def test_vehicles_equal_the_last_solution(run: Run) -> None:
    last = run.solutions[-1]
    body = run.get("/vehicles").json()
    assert body["fleet"] == run.fleet and body["method"] == METHOD
    assert body["epoch"] == last.epoch.model_dump()
    got = {v["vehicle_id"]: v for v in body["vehicles"]}
    assert sorted(got) == sorted(run.vehicles)
    # the fields compared below are filled
    assert any(vs.vdop is not None for vs in last.vehicles) and any(
        plane_source(vs.plane) for vs in last.vehicles
    )
    for vs in last.vehicles:
        v = got[vs.vehicle_id]
        assert tuple(v["position_ecef_m"]) == vs.position_ecef_m  # JSON floats round-trip exactly
        assert v["seq"] == last.seq and v["plane_status"] == vs.plane_status
        assert (v["plane_used"], v["plane_source"]) == (vs.plane_used, plane_source(vs.plane))
        assert v["excluded_satellites"] == vs.excluded_satellites  # the estimator's, by name
        assert (v["raim_excluded"], v["vdop"]) == (vs.raim_excluded, vs.vdop)  # the agent's
        assert v["online"] is False  # the agents have finished: their tokens are gone
        d = run.get(f"/vehicles/{vs.vehicle_id}").json()
        assert d["covariance_m2"] == vs.covariance_m2
        assert d["counters"]["used"] == len(run.solutions)
    assert run.get("/vehicles/ghost").status_code == 404


def test_tracks_equal_the_solution_csvs(run: Run) -> None:
    assert run.csv_dir is not None
    seen: Counter[str] = Counter()  # the fields compared below are filled somewhere
    for vid in run.vehicles:
        rows = _csv_rows(run.csv_dir / f"{vid}.csv")
        pts = run.get(f"/vehicles/{vid}/track").json()["points"]
        assert len(pts) == len(rows) == len(run.solutions)
        for p, row in zip(pts, rows, strict=True):
            assert (p["week"], f"{p['tow']:.3f}") == (int(row["gps_week"]), row["tow_s"])
            assert p["position_ecef_m"] == pytest.approx(
                [float(row["x_m"]), float(row["y_m"]), float(row["z_m"])], abs=6e-5
            )
            c = p["covariance_m2"]
            assert [c[0], c[4], c[8], c[1], c[5], c[2]] == pytest.approx(
                [float(row[k]) for k in ("cov_xx", "cov_yy", "cov_zz", "cov_xy", "cov_yz", "cov_xz")],
                rel=1e-5,
                abs=1e-9,
            )
            # why, per epoch, as the CSV has it
            assert (p["n_satellites"], p["n_pseudoranges"]) == (
                int(row["n_satellites"]),
                int(row["n_pseudoranges"]),
            )
            assert (" ".join(p["excluded_satellites"]), " ".join(p["raim_excluded"])) == (
                row["excluded"],
                row["raim_excluded"],
            )
            for dop in ("hdop", "vdop"):
                assert (p[dop] is None) == (row[dop] == "") and (
                    p[dop] is None or f"{p[dop]:.2f}" == row[dop]
                )
            # and what else held it: ranges, the plane and where it came from
            assert (p["n_ranges"], p["plane_used"], p["plane_source"] or "") == (
                int(row["n_ranges"]),
                row["plane"] == "used",
                row["plane_source"],
            )
            seen.update(k for k in ("n_ranges", "plane_used", "plane_source", "hdop") if p[k])
        since = pts[-4]["gps_s"]
        assert len(run.get(f"/vehicles/{vid}/track", since=since).json()["points"]) == 3
        gj = run.get(f"/vehicles/{vid}/track", format="geojson").json()
        coords = gj["features"][0]["geometry"]["coordinates"]
        assert len(coords) == len(rows)
        lat, lon, h = ecef_to_geodetic([float(rows[-1][k]) for k in ("x_m", "y_m", "z_m")])
        assert coords[-1][:2] == pytest.approx([math.degrees(lon), math.degrees(lat)], abs=1e-8)  # ~1 mm
        assert coords[-1][2] == pytest.approx(h, abs=2e-4)  # the CSV keeps 0.1 mm
    assert set(seen) == {"n_ranges", "plane_used", "plane_source", "hdop"}, seen


def test_accuracy_equals_offline_metrics(run: Run) -> None:
    mrun = MethodRun(METHOD, 0.0)
    for sol in run.solutions:
        record_solution(mrun, sol, {})
    expected = run_stats(mrun, open_recording(run.rec))
    body = run.get("/accuracy").json()
    got = {e["vehicle_id"]: e for e in body["entries"] if e["method"] == METHOD}
    assert sorted(got) == sorted(expected) == sorted(run.vehicles)
    for vid, st in expected.items():
        e = got[vid]
        assert (e["n_solved"], e["n_truth"]) == (st.n_solved, st.n_truth)
        for k in (
            "availability",
            "h_rmse_m",
            "v_rmse_m",
            "cep95_m",
            "h_max_m",
            "v_max_m",
            "h_mean_m",
            "v_bias_m",
        ):
            assert e[k] == pytest.approx(getattr(st, k), rel=1e-9, abs=1e-9), (vid, k)


def test_planes_match_the_solutions(run: Run) -> None:
    body = run.get("/planes").json()
    for p in body["vehicles"]:
        statuses = [
            vs.plane_status or "none"
            for sol in run.solutions
            for vs in sol.vehicles
            if vs.vehicle_id == p["vehicle_id"]
        ]
        counts = p["counts"]
        assert counts["available"] == statuses.count("available")
        assert counts["available_after_fe"] == statuses.count("available-after-fe")
        assert counts["unavailable"] == statuses.count("unavailable")
        assert counts["none"] == statuses.count("none")


def test_metrics_count_the_injected_bad_messages(run: Run) -> None:
    m = _metrics(run.get("/metrics").text)
    n = len(run.solutions)
    v0, v1, v2 = run.vehicles
    assert m["coplane_messages_rejected_total", (("vehicle", v0),)] == BAD_JSON
    assert m["coplane_messages_rejected_total", (("vehicle", v1),)] == BAD_MODEL
    assert m["coplane_messages_rejected_total", (("vehicle", v2),)] == 0
    assert m["coplane_messages_rejected_by_reason_total", (("reason", "invalid-json"),)] == BAD_JSON
    assert m["coplane_messages_rejected_by_reason_total", (("reason", "invalid-message"),)] == BAD_MODEL
    assert m["coplane_messages_rejected_by_reason_total", (("reason", "unknown-vehicle"),)] == UNKNOWN
    for v in run.vehicles:
        lab = (("vehicle", v),)
        assert m["coplane_messages_used_total", lab] == n
        parts = sum(m[f"coplane_messages_{k}_total", lab] for k in ("used", "rejected", "late", "duplicate"))
        assert m["coplane_messages_received_total", lab] == parts  # the server's accounting identity
        assert m["coplane_vehicle_online", lab] == 0
        statuses = [vs.plane_status for s in run.solutions for vs in s.vehicles if vs.vehicle_id == v]
        with_plane = [s for s in statuses if s is not None]
        if with_plane:
            ok = sum(s in ("available", "available-after-fe") for s in with_plane)
            assert m["coplane_plane_availability_ratio", lab] == pytest.approx(ok / len(with_plane))
    assert m["coplane_epochs_solved_total", ()] == n
    assert m["coplane_live_vehicles", ()] == 0
    assert (
        m["coplane_api_rejected_total", (("kind", "invalid-json"), ("source", "solution"))] == BAD_SOLUTIONS
    )
    assert m["coplane_api_solutions_total", ()] == n
    assert m["coplane_solve_time_seconds_count", ()] == n
    assert m["coplane_solve_time_seconds_sum", ()] == pytest.approx(
        sum(s.solve_time_s for s in run.solutions)
    )
    assert m["coplane_epoch_latency_seconds_count", ()] == sum(
        s.oldest_node_sent_unix_s is not None for s in run.solutions
    )
    assert m["coplane_api_ready", ()] == 1 and m["coplane_fusion_servers_alive", ()] == 1
    print(
        f"\nfleet run: {n} epochs x {len(run.vehicles)} vehicles in {run.timings['replay_s']:.1f} s; "
        f"epoch latency mean {1000 * m['coplane_epoch_latency_seconds_sum', ()] / n:.1f} ms"
    )


def test_stream_starts_with_the_latest_solution(run: Run) -> None:
    with httpx.stream("GET", run.url + "/stream", timeout=10) as r:
        assert r.headers["content-type"].startswith("text/event-stream")
        for line in r.iter_lines():
            if line.startswith("data:"):
                ev = json.loads(line[5:])
                break
    assert ev["seq"] == run.solutions[-1].seq and len(ev["vehicles"]) == len(run.vehicles)
    pos = {v["vehicle_id"]: v["enu_m"] for v in ev["vehicles"]}
    track = run.get(f"/vehicles/{run.vehicles[0]}/track", limit=1).json()["points"][0]
    assert np.allclose(pos[run.vehicles[0]], track["enu_m"])


def test_readyz_follows_the_fusion_server_and_the_router(run: Run) -> None:
    """Last in this module: it kills and restarts processes of the shared fleet."""
    assert _ready(run)
    fusion = run.procs.procs["fusion-server"]
    fusion.send_signal(signal.SIGKILL)
    fusion.wait(10)
    t_down = _wait(lambda: not _ready(run), 10, "readyz 503 after killing the fusion server")
    body = run.get("/readyz").json()
    assert any("fusion" in r for r in body["reasons"]) and run.get("/healthz").status_code == 200
    run.procs.start(run.specs["fusion-server"])
    t_up = _wait(lambda: _ready(run), 30, "readyz 200 after restarting the fusion server")
    router = run.procs.procs["zenoh-router"]
    router.send_signal(signal.SIGKILL)
    router.wait(10)
    t_rdown = _wait(lambda: not _ready(run), 10, "readyz 503 after killing the router")
    assert run.get("/vehicles").status_code == 200  # the data stays served without a bus
    run.procs.start(run.specs["zenoh-router"])
    t_rup = _wait(lambda: _ready(run), 40, "readyz 200 after restarting the router")
    m = _metrics(run.get("/metrics").text)
    assert m["coplane_api_solutions_total", ()] == len(run.solutions)  # no replay: nothing new
    print(
        f"\nreadyz: fusion killed -> 503 in {t_down:.2f} s, restarted -> 200 in {t_up:.2f} s; "
        f"router killed -> 503 in {t_rdown:.2f} s, restarted -> 200 in {t_rup:.2f} s"
    )
