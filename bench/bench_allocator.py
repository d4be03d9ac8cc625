"""The fusion estimator's CPU on glibc's malloc and on jemalloc (`coplane.allocator`, issue 16).

    .venv/bin/python bench/bench_allocator.py [--vehicles 256,1000] [--duration 20] [--seed 11]
        [--repeats 3] [--allocators system,jemalloc] [--out docs/performance-scale.md]

For each city size: a simulated city (`coplane simulate --scenario city`, as in
`bench_window_clusters.py`), whose pc estimator inputs are recorded once in this process; then
the estimator alone over them (`bench_window_clusters.replay`: CPU of `FusionEstimator.step` per
vehicle-epoch, every epoch) in a child process per allocator, the allocators taking turns
`--repeats` times so they share the host's drift. A child's allocator can only be chosen when it
starts: "system" runs it with `COPLANE_ALLOCATOR=system` and nothing preloaded, "jemalloc" with
the environment `coplane.allocator` gives the services, a path preloads that library. Each child
reports the allocator it found itself running on. Printed: the median CPU per allocator, its ratio
to the system's median of the same run, the errors, and whether every run gave the same positions
bit for bit.
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import platform
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

from docblock import write_block  # bench/ is the script's directory, first on sys.path

ROOT = Path(__file__).resolve().parents[1]
MARK = "bench_allocator"


def child_env(allocator: str) -> dict[str, str]:
    """This process's environment, with only `allocator` preloaded."""
    from coplane.allocator import allocator_env

    env = {k: v for k, v in os.environ.items() if k not in ("LD_PRELOAD", "COPLANE_ALLOCATOR")}
    if allocator == "system":
        return env | {"COPLANE_ALLOCATOR": "system"}
    choice = {"COPLANE_ALLOCATOR": "auto" if allocator == "jemalloc" else allocator}
    extra = allocator_env(choice)
    if not extra:
        raise SystemExit(f"allocator {allocator!r} is not installed here (Debian: libjemalloc2)")
    return env | extra


def run_child(inputs: Path, rec_dir: Path, allocator: str) -> dict[str, Any]:
    out = subprocess.run(
        [sys.executable, __file__, "--child", str(inputs), str(rec_dir)],
        env=child_env(allocator), check=True, capture_output=True, text=True, cwd=ROOT,
    )  # fmt: skip
    return dict(json.loads(out.stdout.strip().splitlines()[-1]))


def child(inputs: Path, rec_dir: Path) -> int:
    """One replay of the recorded inputs; one JSON line with its figures and its allocator."""
    import bench_window_clusters as recorder

    from coplane.allocator import loaded_allocator

    with inputs.open("rb") as f:
        config, epochs = pickle.load(f)
    r = recorder.replay(rec_dir, config, epochs, config.window_cluster_max)
    print(json.dumps(r | {"allocator": loaded_allocator()}))
    return 0


def compare(vehicles: int, duration: float, seed: int, allocators: list[str], repeats: int) -> dict[str, Any]:
    """Per allocator: its runs' figures, in turn with the others."""
    import bench_window_clusters as recorder

    with tempfile.TemporaryDirectory() as tmp:
        rec_dir = Path(tmp) / "city"
        recorder.simulate_city(rec_dir, vehicles, duration, seed)
        recorded = recorder.record_inputs(rec_dir)
        inputs = Path(tmp) / "inputs.pkl"
        with inputs.open("wb") as f:
            pickle.dump(recorded, f, protocol=pickle.HIGHEST_PROTOCOL)
        runs: dict[str, list[dict[str, Any]]] = {a: [] for a in allocators}
        for _ in range(repeats):
            for a in allocators:
                runs[a].append(run_child(inputs, rec_dir, a))
                print(f"{vehicles} vehicles, {a}: {runs[a][-1]['ms']:.3f} ms", file=sys.stderr, flush=True)
    return runs


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--vehicles", default="256,1000")
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--allocators", default="system,jemalloc")
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--child", nargs=2, type=Path, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        return child(*args.child)
    allocators = [a for a in args.allocators.split(",") if a]
    if allocators[0] != "system":
        allocators.insert(0, "system")  # the reference of the ratios
    rows = [
        f"| city | allocator (as the child found itself) | fusion CPU ms / vehicle-epoch (median of {args.repeats}) "
        "| vs system | H RMSE (m) | V RMSE (m) |",
        "|---|---|---|---|---|---|",
    ]
    digests: set[str] = set()
    for n in [int(v) for v in args.vehicles.split(",")]:
        runs = compare(n, args.duration, args.seed, allocators, args.repeats)
        base = statistics.median(r["ms"] for r in runs["system"])
        for a, rs in runs.items():
            ms = statistics.median(r["ms"] for r in rs)
            found = sorted({r["allocator"] for r in rs})
            rows.append(
                f"| {n} vehicles | {a} ({', '.join(found)}) | {ms:.2f} | {ms / base:.2f} | "
                f"{rs[0]['h']:.3f} | {rs[0]['v']:.3f} |"
            )
            digests |= {f"{n}:{r['digest']}" for r in rs}
    sizes = args.vehicles.split(",")
    same = len(digests) == len(sizes)
    cmd = " ".join(["python", "bench/bench_allocator.py", *sys.argv[1:]])
    text = "\n".join(
        [
            f"machine: {platform.machine()}, Python {platform.python_version()}; cities of "
            f"{args.vehicles} vehicles x {args.duration:g} s (seed {args.seed}), method pc, the estimator "
            f"alone on recorded inputs in a child process per run, allocators in turn {args.repeats} times",
            "",
            *rows,
            "",
            "Positions of every run bit for bit the same within each city: "
            + ("yes." if same else "**no** (the allocator changed results)."),
        ]
    )
    print(text)
    if args.out:
        write_block(args.out, MARK, cmd, text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
