"""Scale-out benchmark (issue 16): a simulated city through 1, 2 and 4 fusion servers by region.

    .venv/bin/python bench/bench_scale.py [--vehicles 256] [--duration 60] [--servers 1,2,4]
                                          [--region-size 1000] [--pace lockstep|realtime]
                                          [--out docs/performance-scale.md [--block NAME]]

For each server count: a Zenoh router, that many fusion servers (`--regions` when more than one)
and one `coplane loadgen` process carrying every vehicle (lockstep or realtime at 1 Hz, insecure
test bus), all plain processes on this machine. `--block` names the generated block of the page
that the table replaces (one per configuration). Measured in the same run: wall time, solved vehicle-epochs per second,
each server's CPU seconds and peak RSS (/proc, read before it is stopped) and the vehicle-epochs it
solved, the load generator's front-end and ingest CPU per vehicle-epoch, and the latency from a
node message's publish to the solution that answers it (p50 / p99). Every process shares the
machine's cores, so the load generator's own work limits the curve; the table says how much.

`--clusters`: instead, the in-process replay (`run_method`, method pc) of the same city with the
step's range bounds (`bounded_ranges`: 8 per vehicle, 16 per cluster) and without them, each in
its own process: wall time and peak RSS.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
from docblock import write_block  # bench/ is the script's directory, first on sys.path

try:
    from coplane.allocator import allocator_env, allocator_library
except ImportError:  # bench_scale_ab.py runs this harness on commits from before coplane.allocator

    def allocator_env() -> dict[str, str]:
        return {}  # those commits' services ran on the system's malloc

    def allocator_library() -> str | None:
        return None


ROOT = Path(__file__).resolve().parents[1]
PY = sys.executable
TICK = os.sysconf("SC_CLK_TCK")


def _cpu_rss(pid: int) -> tuple[float, float]:
    """(user + system CPU seconds, peak RSS MB) of a live process."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    cpu = (int(fields[11]) + int(fields[12])) / TICK
    hwm = next(
        line for line in Path(f"/proc/{pid}/status").read_text().splitlines() if line.startswith("VmHWM")
    )
    return cpu, int(hwm.split()[1]) / 1024.0


def _rss_mb(pid: int) -> float:
    """Current resident set (VmRSS) of a live process, MB."""
    line = next(x for x in Path(f"/proc/{pid}/status").read_text().splitlines() if x.startswith("VmRSS"))
    return int(line.split()[1]) / 1024.0


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def run_one(
    rec: Path, servers: int, region_size: float, logs: Path, pace: str = "lockstep", sample_s: float = 0.0
) -> dict:
    """One configuration; `sample_s` > 0 also samples every server's RSS that often (`rss_series`)."""
    # the processes as `coplane fleet` starts them: on jemalloc where installed (coplane.allocator)
    env = {**os.environ, **allocator_env(), "COPLANE_BUS_INSECURE": "1", "OPENBLAS_CORETYPE": "Haswell"}
    port = _free_port()
    ep = f"tcp/127.0.0.1:{port}"
    procs: list[subprocess.Popen[bytes]] = []

    def start(name: str, args: list[str]) -> subprocess.Popen[bytes]:
        f = (logs / f"{name}.log").open("wb")
        p = subprocess.Popen([PY, *args], env=env, stdout=f, stderr=subprocess.STDOUT, cwd=ROOT)
        procs.append(p)
        return p

    margin = min(500.0, 0.45 * region_size)
    regional = (
        ["--regions", "true", "--region_size_m", str(region_size), "--region_margin_m", str(margin)]
        if servers > 1
        else []
    )
    try:
        start("router", ["-m", "coplane.bus.router", "--listen", ep])
        time.sleep(1.0)
        fusion = []
        for i in range(1, servers + 1):
            ident = ["--server_id", f"s{i}", "--expected_servers", str(servers)] if servers > 1 else []
            fusion.append(
                start(
                    f"fusion-{i}",
                    [
                        "-m",
                        "coplane.fusion_server",
                        "--recording",
                        str(rec),
                        "--method",
                        "pc",
                        "--pace",
                        pace,
                        "--connect",
                        f'["{ep}"]',
                        "--map",
                        "none",
                        "--db",
                        "none",
                        "--diagnostics_period_s",
                        "5",
                        # one load generator publishes every vehicle's epoch in turn, which takes
                        # seconds at 1000 vehicles: a lockstep server must not take the last ones
                        # for silent (the default 5 s is for an agent that died)
                        "--stall_timeout_s",
                        "60",
                        # and its first epoch too: the start waits this long from the first
                        # message for the servers' vehicles to have spoken
                        "--startup_wait_s",
                        "60",
                        *regional,
                        *ident,
                    ],
                )
            )
        time.sleep(2.0)
        before = [_cpu_rss(p.pid)[0] for p in fusion]  # start-up (imports, recording) not counted
        out = logs / "loadgen.json"
        reg = (
            ["--regions", "--region-size", str(region_size), "--region-margin", str(margin)]
            if servers > 1
            else []
        )
        series: list[tuple[float, list[float]]] = []
        done = threading.Event()

        def sample() -> None:
            t0 = time.perf_counter()
            while not done.wait(sample_s):
                series.append((time.perf_counter() - t0, [_rss_mb(p.pid) for p in fusion]))

        sampler = threading.Thread(target=sample, daemon=True)
        if sample_s > 0:
            sampler.start()
        lg = subprocess.run(
            [
                PY,
                "-m",
                "coplane.cli",
                "loadgen",
                str(rec),
                "--insecure",
                "--connect",
                ep,
                "--pace",
                pace,
                *reg,
                "--json",
                str(out),
            ],
            env=env,
            cwd=ROOT,
            capture_output=True,
            timeout=7200,
        )
        done.set()
        (logs / "loadgen.log").write_bytes(lg.stderr)  # its warnings: which epoch went unanswered
        if lg.returncode != 0:
            raise RuntimeError(f"loadgen failed: {lg.stderr.decode()[-2000:]}")
        summary = json.loads(out.read_text())
        per_server = [(c - b, m) for (c, m), b in zip((_cpu_rss(p.pid) for p in fusion), before, strict=True)]
        summary["servers"] = servers
        summary["rss_series"] = series
        summary["server_cpu_s"] = [round(c, 1) for c, _ in per_server]
        summary["server_peak_rss_mb"] = [round(m) for _, m in per_server]
        return summary
    finally:
        for p in reversed(procs):
            p.terminate()
        for p in procs:
            try:
                p.wait(15)
            except subprocess.TimeoutExpired:
                p.kill()


CLUSTER_RUN = """
import resource, sys, time
import coplane.steps.fusion as f
from coplane.evaluate.runner import run_method
from coplane.recording.reader import open_recording
if sys.argv[2] == "unbounded":
    f.bounded_ranges = lambda ranges, per_vehicle, cluster_max: ranges
rec = open_recording(sys.argv[1])
t = time.perf_counter()
run_method(rec, "pc")
print(time.perf_counter() - t, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)
"""


def cluster_table(rec: Path, vehicles: int, duration: float) -> str:
    """Wall time and peak RSS of the in-process replay with and without the range bounds."""
    env = {**os.environ, "OPENBLAS_CORETYPE": "Haswell"}
    lines = [
        f"in-process replay, method pc, city {vehicles} vehicles x {duration:.0f} s:",
        "",
        "| ranges | wall s | peak RSS MB |",
        "|---|---|---|",
    ]
    for mode in ("bounded", "unbounded"):
        out = subprocess.run(
            [PY, "-c", CLUSTER_RUN, str(rec), mode],
            env=env,
            cwd=ROOT,
            capture_output=True,
            check=True,
            text=True,
        )
        wall, rss = (float(x) for x in out.stdout.split()[-2:])
        label = "bounded (8 per vehicle, 16 per cluster)" if mode == "bounded" else "all (no bounds)"
        lines.append(f"| {label} | {wall:.1f} | {rss:.0f} |")
    return "\n".join(lines)


def memory_table(r: dict, args: argparse.Namespace) -> str:
    """One server's resident memory over a long run: ten evenly spaced samples, and the growth of
    the second half (after the window, the histories and the caches have filled)."""
    series = r["rss_series"]
    if len(series) < 4:
        return "too few samples: run longer or sample more often"
    lines = [
        f"machine: {platform.machine()}, {os.cpu_count()} CPUs; city {args.vehicles} vehicles x "
        f"{args.duration:.0f} s, one server, method pc, {args.pace}, allocator {allocator_library() or 'system'}; "
        f"{r['solved']} vehicle-epochs solved in "
        f"{r['wall_s']} s, server peak RSS {r['server_peak_rss_mb'][0]} MB",
        "",
        "| wall s | share of the run | server RSS MB |",
        "|---|---|---|",
    ]
    n = len(series)
    for k in sorted({round(i * (n - 1) / 9) for i in range(10)}):
        t, rss = series[k]
        lines.append(f"| {t:.0f} | {(k + 1) / n:.0%} | {rss[0]:.0f} |")
    half = [x[1][0] for x in series[n // 2 :]]
    # growth as a least-squares slope, not two samples of a band that breathes with the garbage
    # collector; per 10 minutes of the drive (lockstep runs faster than real time)
    slope = (
        float(np.polyfit([x[0] for x in series[n // 2 :]], half, 1)[0]) * float(r["wall_s"]) / args.duration
    )
    lines += [
        "",
        f"second half: {min(half):.0f} .. {max(half):.0f} MB, last - first {half[-1] - half[0]:+.0f} MB; "
        f"trend {600 * slope:+.1f} MB per 10 minutes of the drive (least squares over its {len(half)} samples)",
    ]
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--vehicles", type=int, default=256)
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--servers", default="1,2,4")
    ap.add_argument("--region-size", type=float, default=1000.0)
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--clusters", action="store_true", help="the range-bounds table instead")
    ap.add_argument("--pace", choices=("lockstep", "realtime"), default="lockstep")
    ap.add_argument(
        "--memory", type=float, default=0.0, help="one server, its RSS sampled every this many seconds"
    )
    ap.add_argument("--block", default="bench_scale", help="the generated block of --out to replace")
    args = ap.parse_args()
    work = Path(tempfile.mkdtemp(prefix="coplane-scale-"))
    print(f"city and every process's log kept in {work} (delete it when done)", file=sys.stderr)
    rec = work / "city"
    t0 = time.perf_counter()
    subprocess.run(
        [PY, "-m", "coplane.cli", "simulate", "--scenario", "city", "--vehicles", str(args.vehicles),
         "--duration", str(args.duration), "--seed", str(args.seed), "--out", str(rec)],
        check=True, capture_output=True, cwd=ROOT,
    )  # fmt: skip
    sim_s = time.perf_counter() - t0
    if args.clusters:
        table = cluster_table(rec, args.vehicles, args.duration)
        print(table)
        if args.out is not None:
            _write_doc(args.out, table, args, "bench_scale_clusters", "--clusters ")
        return 0
    if args.memory > 0:
        logs = work / "memory"
        logs.mkdir()
        r = run_one(rec, 1, args.region_size, logs, args.pace, sample_s=args.memory)
        table = memory_table(r, args)
        print(table)
        if args.out is not None:
            _write_doc(args.out, table, args, "bench_scale_memory", f"--memory {args.memory:g} ")
        return 0
    rows = []
    for n in (int(x) for x in args.servers.split(",")):
        logs = work / f"servers-{n}"
        logs.mkdir()
        rows.append(run_one(rec, n, args.region_size, logs, args.pace))
        print(json.dumps(rows[-1]), flush=True)
    base = rows[0]["vehicle_epochs_per_s"] or 1.0
    lines = [
        f"machine: {platform.machine()}, {os.cpu_count()} CPUs, Python {platform.python_version()}; "
        f"city {args.vehicles} vehicles x {args.duration:.0f} s (seed {args.seed}, simulated in {sim_s:.0f} s), "
        f"regions {args.region_size:.0f} m, method pc, {args.pace}; allocator {allocator_library() or 'system'}",
        "",
        "| fusion servers | wall s | solved vehicle-epochs/s | vs 1 server | fusion CPU ms per vehicle-epoch (all servers) "
        "| server CPU s (each) | server peak RSS MB (each) | loadgen front end ms / vehicle-epoch | loadgen ingest ms / "
        "vehicle-epoch | latency p50 / p99 s | unanswered | extra answers |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        fusion_ms = 1e3 * sum(r["server_cpu_s"]) / max(1, r["solved"])
        lines.append(
            f"| {r['servers']} | {r['wall_s']} | {r['vehicle_epochs_per_s']} | "
            f"{(r['vehicle_epochs_per_s'] or 0) / base:.2f} | {fusion_ms:.2f} | "
            f"{' / '.join(str(c) for c in r['server_cpu_s'])} | "
            f"{' / '.join(str(m) for m in r['server_peak_rss_mb'])} | {r['front_end_ms_per_vehicle_epoch']} | "
            f"{r['ingest_ms_per_vehicle_epoch']} | {r['latency_p50_s']} / {r['latency_p99_s']} | {r['unanswered']} | "
            f"{r['extra_answers']} |"
        )
    table = "\n".join(lines)
    print(table)
    if args.out is not None:
        _write_doc(args.out, table, args, args.block, "")
    return 0


def _write_doc(path: Path, table: str, args: argparse.Namespace, marker: str, flag: str) -> None:
    """Replace the generated block `marker` of the performance page with `table`."""
    servers = (
        "" if flag else f"--servers {args.servers} --region-size {args.region_size:.0f} --pace {args.pace} "
    )
    if marker != "bench_scale" and not flag:
        servers += f"--block {marker} "
    cmd = (
        f"python bench/bench_scale.py {flag}--vehicles {args.vehicles} --duration {args.duration:.0f} "
        f"{servers}--out {path}"
    )
    write_block(path, marker, cmd, table)


if __name__ == "__main__":
    raise SystemExit(main())
