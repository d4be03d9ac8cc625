"""Clean shutdown (issue 13): Ctrl-C and SIGTERM of every command and service, timed.

    .venv/bin/python bench/reliability_shutdown.py      # about 5 minutes on 2 cores
    .venv/bin/python bench/reliability_shutdown.py --repeats 1

Each case starts the process(es) as a user would, in their own process group, waits until they
are in the state named, then sends the signal: "Ctrl-C" is SIGINT to the whole process group (what
a terminal does), "SIGTERM" goes to the top process alone (`kill PID`, `docker stop`), which must
stop its children itself. Measured: the exit code, the seconds until the top process exited and
until the last of its descendants was gone (exited and reaped), and any process left after 10 s.
The fleet runs secure (mutual TLS, access control), as by default.

Writes docs/reliability/shutdown.md.
"""

from __future__ import annotations

import argparse
import datetime as dt
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))
from support.e2e_fleet import StopTiming, signal_and_time, start_serving_fleet  # noqa: E402

from coplane.fleet import free_port, wait_for_port  # noqa: E402
from coplane.sim.generate import ensure_default_recording, simulate  # noqa: E402

OUT = REPO / "docs" / "reliability" / "shutdown.md"
PY = sys.executable


@dataclass
class Case:
    name: str
    state: str  # what it was doing when signalled
    sig: int
    group: bool
    start: Callable[[Path], subprocess.Popen[bytes]]


def _spawn(args: list[str], work: Path, env: dict[str, str] | None = None) -> subprocess.Popen[bytes]:
    log = (work / "out.log").open("wb")
    p = subprocess.Popen(
        [PY, "-m", *args], stdout=log, stderr=log, start_new_session=True, env={**os.environ, **(env or {})}
    )
    log.close()
    return p


def _wait_for_text(path: Path, text: str, p: subprocess.Popen[bytes], timeout: float = 240.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if path.exists() and text in path.read_text(errors="replace"):
            return
        if p.poll() is not None:
            raise RuntimeError(f"{p.args} ended before {text!r}")
        time.sleep(0.1)
    raise TimeoutError(f"{text!r} not in {path} after {timeout} s")


def cases(short: Path, long: Path) -> list[Case]:
    insecure = {"COPLANE_BUS_INSECURE": "1"}

    def serving(work: Path) -> subprocess.Popen[bytes]:
        return start_serving_fleet(short, work)

    def replaying(work: Path) -> subprocess.Popen[bytes]:
        args = ["coplane.cli", "fleet", str(long), "--port", "0", "--api-port", str(free_port())]
        p = _spawn([*args, "--certs", str(work / "certs"), "--logs", str(work / "logs")], work)
        _wait_for_text(work / "logs" / "agent-u1.log", "agent started", p)
        time.sleep(2.0)  # mid-replay
        return p

    def evaluating(work: Path) -> subprocess.Popen[bytes]:
        rec = str(ensure_default_recording())  # 10 minutes: long enough to be caught mid-run
        p = _spawn(["coplane.cli", "eval", rec, "--methods", "pc,mci", "--out", str(work / "eval")], work)
        _wait_for_text(work / "out.log", "epoch/s", p)  # workers forked, epochs being solved
        time.sleep(1.0)
        return p

    def service(kind: str) -> Callable[[Path], subprocess.Popen[bytes]]:
        def start(work: Path) -> subprocess.Popen[bytes]:
            port, api_port = free_port(), free_port()
            connect = f'["tcp/127.0.0.1:{port}"]'
            router = _spawn(["coplane.bus.router", "--listen", f"tcp/127.0.0.1:{port}"], work, insecure)
            wait_for_port(port)
            if kind == "router":
                return router
            work.joinpath("router.pid").write_text(str(router.pid))
            rec = ["--recording", str(long), "--connect", connect]
            args = {
                "fusion": ["coplane.fusion_server", *rec, "--pace", "realtime"],
                "agent": ["coplane.vehicle_agent", *rec, "--vehicle_id", "u1", "--pace", "realtime"],
                "api": ["coplane.api", *rec, "--port", str(api_port)],
            }[kind]
            p = _spawn(args, work, insecure)
            if kind == "api":
                wait_for_port(api_port, 120)
            time.sleep(4.0)  # imported, on the bus
            assert p.poll() is None, (work / "out.log").read_text()[-2000:]
            return p

        return start

    out = [
        Case("`coplane fleet --serve`", "serving the API after the replay", signal.SIGINT, True, serving),
        Case("`coplane fleet --serve`", "serving the API after the replay", signal.SIGTERM, False, serving),
        Case("`coplane fleet`", "mid-replay, 4 agents running", signal.SIGINT, True, replaying),
        Case("`coplane fleet`", "mid-replay, 4 agents running", signal.SIGTERM, False, replaying),
        Case(
            "`coplane eval --methods pc,mci`",
            "mid-run, vehicle workers forked",
            signal.SIGINT,
            True,
            evaluating,
        ),
        Case(
            "`coplane eval --methods pc,mci`",
            "mid-run, vehicle workers forked",
            signal.SIGTERM,
            False,
            evaluating,
        ),
    ]
    for kind, module in (
        ("router", "coplane.bus.router"),
        ("fusion", "coplane.fusion_server"),
        ("agent", "coplane.vehicle_agent"),
        ("api", "coplane.api"),
    ):
        for sig in (signal.SIGINT, signal.SIGTERM):
            out.append(Case(f"`python -m {module}`", "running, on the bus", sig, False, service(kind)))
    return out


def measure(case: Case, repeats: int, root: Path) -> list[StopTiming]:
    got = []
    for r in range(repeats):
        work = root / f"{len(list(root.iterdir()))}-{r}"
        work.mkdir()
        p = case.start(work)
        got.append(signal_and_time(p, case.sig, case.group))
        pid_file = work / "router.pid"
        if pid_file.exists():  # the router a service case needed
            os.kill(int(pid_file.read_text()), signal.SIGTERM)
            time.sleep(0.5)
    return got


def render(rows: list[tuple[Case, list[StopTiming]]], repeats: int) -> str:
    lines = [
        "# Shutdown: Ctrl-C and SIGTERM of every command and service",
        "",
        "Regenerate: `.venv/bin/python bench/reliability_shutdown.py` "
        f"(written {dt.date.today().isoformat()}; every number below comes from that run, "
        f"{repeats} runs per row, on this 2-core machine).",
        "",
        "Ctrl-C is SIGINT to the process group (as a terminal sends it); SIGTERM goes to the top "
        "process alone, which stops its children itself. Every process handles both "
        "(`coplane.runtime.stop_event`): it ends its loop, withdraws its liveliness token, closes its "
        "session and files, and exits 128 + the signal; a watchdog cuts a stop that hangs after "
        "3 s. `coplane fleet` sends SIGTERM to all its processes at once and reaps them, killing "
        "what is left after 3 s (the router last). Times: until the top process exited / until "
        "the last descendant was gone; median and max over the runs.",
        "",
        "| command | state | signal | exit codes | top exited, s (median / max) | all gone, s (median / max) | processes | left after 10 s |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for case, ts in rows:
        how = (
            "Ctrl-C (group)"
            if case.group
            else "SIGTERM (top only)"
            if case.sig == signal.SIGTERM
            else "SIGINT"
        )
        codes = ", ".join(sorted({str(t.code) for t in ts}))
        parent = [t.parent_s for t in ts]
        alls = [t.all_s for t in ts]
        lines.append(
            f"| {case.name} | {case.state} | {how} | {codes} | "
            f"{statistics.median(parent):.2f} / {max(parent):.2f} | {statistics.median(alls):.2f} / {max(alls):.2f} | "
            f"{max(t.n_processes for t in ts) + 1} | {sum(len(t.left) for t in ts)} |"
        )
    worst = max(max(t.all_s for t in ts) for _, ts in rows)
    ok = all(t.code == 128 + c.sig and not t.left for c, ts in rows for t in ts)
    lines += [
        "",
        f"Slowest stop: {worst:.2f} s (the acceptance limit is 5 s). "
        + (
            "Every run exited 128 + the signal with no process left."
            if ok
            else "**Some runs failed the rule above.**"
        ),
        "",
        "`tests/fleet/test_shutdown.py` asserts the same on every CI run (`coplane fleet --serve` "
        "under Ctrl-C and SIGTERM, and each service).",
    ]
    return "\n".join(lines) + "\n"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="coplane-shutdown-") as tmp:
        root = Path(tmp)
        short = simulate("urban-loop", root / "short", vehicles=2, duration_s=10, seed=5)
        long = simulate("urban-loop", root / "long", vehicles=4, duration_s=120, seed=5)
        runs = root / "runs"
        runs.mkdir()
        rows = []
        for case in cases(short, long):
            ts = measure(case, args.repeats, runs)
            print(f"{case.name} {case.state} {signal.Signals(case.sig).name}: {ts}", flush=True)
            rows.append((case, ts))
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(render(rows, args.repeats))
    print(f"wrote {OUT}")
    return 0 if all(t.code == 128 + c.sig and not t.left and t.all_s < 5 for c, ts in rows for t in ts) else 1


if __name__ == "__main__":
    raise SystemExit(main())
