"""A/B of a fusion server's cost at two commits, measured in turn on the same machine.

    .venv/bin/python bench/bench_scale_ab.py --base REV [--head HEAD] [--vehicles 256]
        [--duration 20] [--repeats 2] [--out docs/performance-scale.md [--block NAME]]

The host's speed drifts by tens of percent between days and by several percent within an hour
(docs/performance-scale.md), so a before/after figure is only worth quoting when both sides ran
alternately, minutes apart: this script runs `bench/bench_scale.py` (this checkout's harness,
one server, lockstep, 1000 m regions) against the library and services of `--base` and of
`--head` in turn (base, head, base, head, ...) and prints each run's fusion CPU per
vehicle-epoch, the load generator's front end (the same code on both sides unless the commits
changed it: the host's drift while the A/B ran), their ratio (the fusion CPU with the host's
speed during that run taken out, when the front end is the same code), the node messages the
load generator re-sent per vehicle-epoch (lockstep, unanswered yet; "-" for a commit whose load
generator did not count them) and the medians.

Each side's code is `git archive` of that commit unpacked in a temporary directory and put first
on PYTHONPATH for the bench and every process it starts, with the services moved into the
`coplane` package as the project's editable install maps them (`package-dir` in that commit's
pyproject.toml): nothing in the working tree changes, and uncommitted edits are in neither side.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import tomllib
from pathlib import Path

from docblock import machine, publish  # bench/ is the script's directory, first on sys.path

ROOT = Path(__file__).resolve().parents[1]
PY = sys.executable


def _short(rev: str) -> str:
    """The short hash of commit `rev`; exits with a message naming `rev` when git cannot resolve
    it to a commit."""
    got = subprocess.run(
        ["git", "rev-parse", "--short", f"{rev}^{{commit}}"], cwd=ROOT, capture_output=True, text=True
    )
    if got.returncode != 0:
        raise SystemExit(f"bench_scale_ab.py: {rev!r} is not a commit of this repository")
    return got.stdout.strip()


def unpack(rev: str, into: Path) -> tuple[str, Path]:
    """The commit `rev` unpacked into `into`, as an importable `coplane` package: returns (its
    short hash, the directory to put on PYTHONPATH)."""
    short = _short(rev)
    tree = into / short
    tree.mkdir(parents=True)
    archive = subprocess.run(["git", "archive", short], cwd=ROOT, check=True, capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(tree)], input=archive, check=True)
    dirs = tomllib.loads((tree / "pyproject.toml").read_text())["tool"]["setuptools"]["package-dir"]
    top = tree / dirs["coplane"]
    for name, where in dirs.items():
        if name != "coplane":  # a service: coplane.<name> lives in its own folder
            shutil.move(str(tree / where), str(top / name.split(".", 1)[1]))
    return short, top.parent


def environment(path: Path) -> dict[str, str]:
    """This process's environment with `path` first on PYTHONPATH (ahead of the editable install)."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(path), env.get("PYTHONPATH", "")) if p)
    return env


def check_imports(short: str, env: dict[str, str], path: Path) -> None:
    """Fail unless the library and the fusion server import from the unpacked commit."""
    probe = "import coplane, coplane.fusion_server as f; print(coplane.__file__); print(f.__file__)"
    out = subprocess.run([PY, "-c", probe], env=env, check=True, capture_output=True, text=True).stdout
    for line in out.split():
        if not Path(line).resolve().is_relative_to(path.resolve()):
            raise SystemExit(f"{short}: {line} is not from {path}: the A/B would measure the wrong code")


def run_once(env: dict[str, str], args: argparse.Namespace) -> dict[str, float]:
    """One `bench_scale.py` run with one server: its JSON row."""
    cmd = [
        PY, str(ROOT / "bench" / "bench_scale.py"), "--vehicles", str(args.vehicles),
        "--duration", str(args.duration), "--servers", "1", "--region-size", "1000", "--pace", "lockstep",
    ]  # fmt: skip
    out = subprocess.run(cmd, env=env, cwd=ROOT, check=True, capture_output=True, text=True).stdout
    row: dict[str, float] = json.loads(next(x for x in out.splitlines() if x.startswith("{")))
    return row


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--base", required=True, help="the commit before the change")
    ap.add_argument("--head", default="HEAD", help="the commit after it")
    ap.add_argument("--vehicles", type=int, default=256)
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--repeats", type=int, default=2, help="runs of each side, alternating")
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--block", default="bench_scale_ab")
    args = ap.parse_args()
    if len({_short(args.base), _short(args.head)}) == 1:
        ap.error(f"--base {args.base} and --head {args.head} are the same commit")
    work = Path(tempfile.mkdtemp(prefix="coplane-ab-"))
    try:
        sides = []
        for rev in (args.base, args.head):
            short, path = unpack(rev, work)
            env = environment(path)
            check_imports(short, env, path)
            sides.append((short, env))
        runs: dict[str, list[tuple[float, float]]] = {short: [] for short, _ in sides}
        rows = [
            "| run | commit | fusion CPU ms / vehicle-epoch | loadgen front end ms / vehicle-epoch "
            "| fusion / front end | re-sent node messages / vehicle-epoch |",
            "|---|---|---|---|---|---|",
        ]
        for _ in range(args.repeats):
            for short, env in sides:
                r = run_once(env, args)
                fusion = 1e3 * sum(r["server_cpu_s"]) / max(1, r["solved"])
                runs[short].append((fusion, r["front_end_ms_per_vehicle_epoch"]))
                front = r["front_end_ms_per_vehicle_epoch"]
                # a load generator from before it counted its re-sends: "-"
                resent = f"{r['resent'] / max(1, r['published']):.2f}" if "resent" in r else "-"
                rows.append(
                    f"| {len(rows) - 1} | {short} | {fusion:.2f} | {front} | {fusion / front:.3f} | {resent} |"
                )
                print(rows[-1], file=sys.stderr, flush=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    (b, bv), (h, hv) = ((s, runs[s]) for s, _ in sides)
    med_b, med_h = (statistics.median(x[0] for x in v) for v in (bv, hv))
    # the front end is the same code on both sides unless the commits changed it, so fusion over
    # front end takes out how fast the host ran during each run (it drifts by 10-20 % between
    # runs minutes apart on a slow day, more than a change of a few percent)
    rel_b, rel_h = (statistics.median(x[0] / x[1] for x in v) for v in (bv, hv))
    rows += [
        "",
        f"median fusion CPU per vehicle-epoch: {b} {med_b:.2f} ms, {h} {med_h:.2f} ms, "
        f"{h} / {b} = {med_h / med_b:.2f}; median fusion / front end: {b} {rel_b:.3f}, {h} {rel_h:.3f}, "
        f"{h} / {b} = {rel_h / rel_b:.2f}",
    ]
    head = (
        f"machine: {machine()}; city {args.vehicles} vehicles x {args.duration:.0f} s (seed 11), one server, "
        f"1000 m regions, lockstep; each commit run {args.repeats} times, alternating"
    )
    command = (
        f"python bench/bench_scale_ab.py --base {b} --head {h} --vehicles {args.vehicles} "
        f"--duration {args.duration:g} --repeats {args.repeats}"
        + (f" --block {args.block}" if args.block != "bench_scale_ab" else "")
        + (f" --out {args.out}" if args.out else "")
    )
    publish(args.out, args.block, command, head, rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
