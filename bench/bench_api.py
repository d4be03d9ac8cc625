"""API latency under load: `python bench/bench_api.py [--recording DIR] [--rate 300] [--duration 10]`.

Starts a Zenoh router, the API, a fusion server and the recording's agents as processes (as
`coplane fleet` does), and drives GET /vehicles from a loopback client at a fixed request rate
(a few workers, each paced; bounded by --duration and --max-requests, then it stops) in three
phases: while a realtime replay runs, while a lockstep replay runs (agents and server saturate the
CPU), and idle after the replay. Prints a Markdown table; `--out docs/performance.md` rewrites
its block there ("API latency").
Latency is per request, client-side (send to full body), so it includes the Python client.
"""

from __future__ import annotations

import argparse
import tempfile
import threading
import time
from pathlib import Path

import httpx
import numpy as np

from coplane.fleet import FleetProcesses, fleet_of, fleet_services, free_port, router_spec, wait_for_port


def load(
    url: str, rate: float, duration: float, max_requests: int, workers: int
) -> tuple[list[float], int, float]:
    """(latencies in ms, errors, wall seconds): `workers` paced clients sharing `rate` requests/s."""
    lat: list[float] = []
    errors = 0
    lock = threading.Lock()
    per_worker = max(1, max_requests // workers)
    interval = workers / rate
    t0 = time.perf_counter() + 0.05

    def worker(i: int) -> None:
        nonlocal errors
        nxt = t0 + i / rate
        mine: list[float] = []
        bad = 0
        with httpx.Client(base_url=url, timeout=5.0) as c:
            for _ in range(per_worker):
                now = time.perf_counter()
                if now - t0 > duration:
                    break
                if nxt > now:
                    time.sleep(nxt - now)
                nxt += interval
                s = time.perf_counter()
                try:
                    r = c.get("/vehicles")
                    ok = r.status_code == 200 and r.content[:1] == b"{"
                except httpx.HTTPError:
                    ok = False
                mine.append(1000 * (time.perf_counter() - s))
                bad += not ok
        with lock:
            lat.extend(mine)
            errors += bad

    threads = [threading.Thread(target=worker, args=(i,)) for i in range(workers)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    return lat, errors, time.perf_counter() - t0


def solutions_seen(url: str) -> int:
    for line in httpx.get(url + "/metrics", timeout=5).text.splitlines():
        if line.startswith("coplane_api_solutions_total "):
            return int(float(line.split()[1]))
    return 0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument(
        "--recording", type=Path, default=None, help="default: a simulated 8-vehicle, 600 s fleet (made here)"
    )
    ap.add_argument("--rate", type=float, default=300.0, help="requests per second")
    ap.add_argument("--duration", type=float, default=10.0, help="seconds of load per phase")
    ap.add_argument("--max-requests", type=int, default=5000, help="cap per phase")
    ap.add_argument("--workers", type=int, default=4, help="concurrent paced clients")
    ap.add_argument("--speed", type=float, default=10.0, help="realtime replay speed factor")
    ap.add_argument(
        "--phases", default="realtime,lockstep,idle", help="comma-separated subset of realtime,lockstep,idle"
    )
    ap.add_argument("--logs", type=Path, default=None)
    ap.add_argument("--out", type=Path, default=None, help="rewrite the bench_api block of this page")
    args = ap.parse_args()
    tmp = tempfile.TemporaryDirectory(prefix="bench-api-")
    made = args.recording is None
    if made:
        from coplane.sim.generate import simulate

        args.recording = simulate(out_dir=Path(tmp.name) / "rec", vehicles=8, duration_s=600.0, seed=0)
    rec = args.recording.resolve()
    _, vehicles = fleet_of(rec)
    rport, aport = free_port(), free_port()
    connect = f"tcp/127.0.0.1:{rport}"
    url = f"http://127.0.0.1:{aport}"
    procs = FleetProcesses(log_dir=args.logs)
    rows = []

    def replay(pace: str) -> None:
        for s in fleet_services(rec, "pc", pace, args.speed, connect, vehicles, False):
            procs.start(s)
        t0 = time.monotonic()
        while solutions_seen(url) < 5 and time.monotonic() - t0 < 60:
            time.sleep(0.1)

    def replay_running() -> bool:
        return any(p.poll() is None for n, p in procs.procs.items() if n.startswith("agent-"))

    def phase(name: str, with_load: bool = True) -> None:
        n0 = solutions_seen(url)
        if not with_load:  # the replay's own pace, for comparison
            t0 = time.perf_counter()
            time.sleep(args.duration)
            wall = time.perf_counter() - t0
            if not replay_running():
                name += " (replay ended early)"
            rows.append(
                f"| {name} | - | - | - | - | - | - | - | - | {(solutions_seen(url) - n0) / wall:.1f} |"
            )
            return
        running = replay_running()
        lat, errors, wall = load(url, args.rate, args.duration, args.max_requests, args.workers)
        sols = solutions_seen(url) - n0
        if running and not replay_running():
            name += " (replay ended early)"
        body = httpx.get(url + "/vehicles", timeout=5).json()
        a = np.array(lat)
        rows.append(
            f"| {name} | {len(a)} | {len(a) / wall:.0f} | {np.percentile(a, 50):.2f} | "
            f"{np.percentile(a, 90):.2f} | {np.percentile(a, 99):.2f} | {a.max():.1f} | {errors} | "
            f"{len(body['vehicles'])} | {sols / wall:.1f} |"
        )

    try:
        procs.start(router_spec(rport))
        wait_for_port(rport)
        specs = fleet_services(rec, "pc", "realtime", 1, connect, [], True, aport)
        procs.start(next(s for s in specs if s.name == "api"))  # as `coplane fleet` starts it
        wait_for_port(aport, 30)
        phases = [p.strip() for p in args.phases.split(",") if p.strip()]
        for pace in ("realtime", "lockstep"):
            if pace not in phases:
                continue
            replay(pace)
            phase(f"realtime replay x{args.speed:g}" if pace == "realtime" else "lockstep replay (CPU-bound)")
            if pace == "lockstep":
                phase("lockstep replay, no HTTP load", with_load=False)
            for name in [n for n in procs.procs if n.startswith("agent-")] + ["fusion-server"]:
                procs.stop(name)
        if "idle" in phases:
            phase("idle (after replay)")
    finally:
        procs.stop_all()
        tmp.cleanup()
    from docblock import machine, publish

    head = (
        f"machine: {machine()}; recording {'a simulated 8-vehicle, 600 s fleet' if made else rec.name} "
        f"({len(vehicles)} vehicles); GET /vehicles at {args.rate:g} req/s from {args.workers} loopback "
        f"clients, {args.duration:g} s per phase"
    )
    table = (
        "| phase | requests | req/s | p50 ms | p90 ms | p99 ms | max ms | errors | vehicles | solutions/s |\n"
        "|---|---|---|---|---|---|---|---|---|---|"
    )
    rows = table.split("\n") + rows
    cmd = "python bench/bench_api.py" + (f" --out {args.out}" if args.out else "")
    publish(args.out, "bench_api", cmd, head, rows)


if __name__ == "__main__":
    main()
