"""End-to-end latency of the fleet over Zenoh: oldest node message of an epoch -> its solution.

Runs router, fusion server and one agent process per vehicle on this machine (loopback only) for a
simulated urban recording, in lockstep and in realtime (speed 1, deadline 0.3 s), and prints a
Markdown table of p50/p99 latency per fleet size. The latency is measured where a user sees it:
at a subscriber of the solution key, against the publish time the agent stamped on the oldest
node message of that epoch.

    .venv/bin/python bench/bench_e2e.py --vehicles 4 64 --duration 30 [--out docs/performance.md]
"""

from __future__ import annotations

import argparse
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

from coplane.bus import KeySpace, decode, payload_bytes, session_config
from coplane.fleet import FleetProcesses, fleet_of, fleet_services, free_port, router_spec, wait_for_port
from coplane.messages import SolutionMessage
from coplane.sim.generate import simulate


def measure(recording: Path, pace: str, n_epochs: int) -> tuple[list[float], float]:
    fleet, vehicles = fleet_of(recording)
    port = free_port()
    connect = f"tcp/127.0.0.1:{port}"
    procs = FleetProcesses()
    lat: list[float] = []
    lock = threading.Lock()

    def on_solution(sample: Any) -> None:
        now = time.time()
        sol = decode(SolutionMessage, payload_bytes(sample))
        if sol.oldest_node_sent_unix_s is not None and sol.seq >= 2:  # skip start-up epochs
            with lock:
                lat.append(now - sol.oldest_node_sent_unix_s)

    try:
        procs.start(router_spec(port))
        wait_for_port(port)
        session = zenoh.open(session_config("client", [connect]))
        session.declare_subscriber(KeySpace(fleet).solution, on_solution)
        start = time.time() + 10.0 + 2.0 * len(vehicles) if pace == "realtime" else None  # all agents up
        specs = fleet_services(recording, "pc", pace, 1.0, connect, vehicles, api=False, start_unix_s=start)
        specs[0].args += ["--deadline_s", "0.3", "--startup_wait_s", str(30 + len(vehicles))]
        t0 = time.monotonic()
        for s in specs:
            procs.start(s)
        while any(p.poll() is None for n, p in procs.procs.items() if n.startswith("agent-")):
            time.sleep(0.2)
        wall = time.monotonic() - t0
        session.close()
    finally:
        procs.stop_all()
    return lat, wall


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--vehicles", type=int, nargs="+", default=[4, 64])
    ap.add_argument("--duration", type=float, default=30.0)
    ap.add_argument("--paces", nargs="+", default=["lockstep", "realtime"])
    ap.add_argument("--out", type=Path, default=None, help="rewrite the bench_e2e block of this page")
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for m in args.vehicles:
            rec = simulate("urban-loop", Path(tmp) / f"r{m}", vehicles=m, duration_s=args.duration, seed=1)
            for pace in args.paces:
                lat, wall = measure(rec, pace, int(args.duration))
                a = np.array(lat) * 1000
                if len(a) == 0:
                    rows.append(f"| {m} | {pace} | 0 | - | - | - | {wall:.0f} |")
                    print(rows[-1], "(no solution received)", flush=True)
                    continue
                rows.append(
                    f"| {m} | {pace} | {len(a)} | {np.percentile(a, 50):.0f} | {np.percentile(a, 99):.0f} | {a.max():.0f} | {wall:.0f} |"
                )
                print(rows[-1], flush=True)
    from docblock import machine, publish

    head = (
        f"machine: {machine()}; simulated urban loop, {int(args.duration)} epochs. Oldest node message "
        "of an epoch (agent publish) -> solution received by a subscriber. Lockstep waits for every "
        "vehicle; realtime solves 0.3 s after an epoch's first message. The first two epochs (process "
        "start-up) are not counted."
    )
    table = "| vehicles | pace | epochs | p50 ms | p99 ms | max ms | wall s |\n|---|---|---|---|---|---|---|"
    rows = table.split("\n") + rows
    cmd = (
        f"python bench/bench_e2e.py --vehicles {' '.join(map(str, args.vehicles))} --duration {args.duration:g}"
        + (f" --paces {' '.join(args.paces)}" if args.paces != ["lockstep", "realtime"] else "")
        + (f" --out {args.out}" if args.out else "")
    )
    publish(args.out, "bench_e2e", cmd, head, rows)


if __name__ == "__main__":
    main()
