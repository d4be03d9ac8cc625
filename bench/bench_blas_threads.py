"""Methods with one BLAS thread per process (coplane's default) against the BLAS's own threads.

    .venv/bin/python bench/bench_blas_threads.py [--repeats 3] [--out docs/performance.md]

Importing coplane limits numpy's and scipy's OpenBLAS to one thread (`coplane.blas_threads`);
`COPLANE_BLAS_THREADS=` (empty) leaves them with their own (one per core). Each method runs on one
simulated urban-loop recording (training seed 101, 4 vehicles x 200 s, DGNSS, the default jobs) in
a fresh process per setting, the two settings alternating within each repeat; the table gives the
median wall time of `run_method` and whether the positions are the same bits (a SHA-256 of every
solved position).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))
MARK = "bench_blas_threads"
METHODS = ("pc", "non-cp-ekf", "dd-cp", "gamp-cp")
SETTINGS = {"one BLAS thread (default)": "1", "the BLAS's own threads": ""}


def child(recording: Path, method: str) -> None:
    """One run in this process: print its wall time and a digest of its positions."""
    from coplane.evaluate.runner import run_method
    from coplane.recording.reader import open_recording

    run = run_method(open_recording(recording), method)
    h = hashlib.sha256()
    for vid in sorted(run.positions):
        for t in sorted(run.positions[vid]):
            h.update(np.asarray(run.positions[vid][t], dtype=float).tobytes())
    print(json.dumps({"wall_s": run.wall_time_s, "digest": h.hexdigest()}))


def run_child(recording: Path, method: str, threads: str) -> dict[str, object]:
    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "COPLANE_BLAS_THREADS")}
    env["COPLANE_BLAS_THREADS"] = threads
    out = subprocess.run(
        [sys.executable, __file__, "--child", str(recording), method],
        env=env,
        capture_output=True,
        text=True,
        check=True,
    )
    result: dict[str, object] = json.loads(out.stdout.strip().splitlines()[-1])
    return result


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--child", nargs=2, metavar=("RECORDING", "METHOD"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        child(Path(args.child[0]), args.child[1])
        return 0
    from docblock import machine, publish

    from coplane.evaluate.benchmark import TRAINING, make_recordings

    seed = TRAINING["urban-loop"][0]
    rows = [
        "| method | " + " | ".join(f"wall s, {s}" for s in SETTINGS) + " | ratio | same positions |",
        "|---|---|---|---|---|",
    ]
    with tempfile.TemporaryDirectory(prefix="coplane-blas-") as tmp:
        rec = make_recordings("urban-loop", [seed], Path(tmp), 4, 200.0)[0].manifest.root
        for method in METHODS:
            walls: dict[str, list[float]] = {s: [] for s in SETTINGS}
            digests: set[object] = set()
            for _ in range(args.repeats):
                for name, threads in SETTINGS.items():
                    r = run_child(rec, method, threads)
                    walls[name].append(float(r["wall_s"]))  # type: ignore[arg-type]
                    digests.add(r["digest"])
            med = [float(np.median(w)) for w in walls.values()]
            rows.append(
                f"| {method} | {med[0]:.1f} | {med[1]:.1f} | {med[0] / med[1]:.2f} | "
                f"{'yes' if len(digests) == 1 else 'no'} |"
            )
            print(rows[-1], flush=True)
    head = (
        f"machine: {machine()}; "
        f"urban-loop seed {seed} (training), 4 vehicles x 200 s, DGNSS, default jobs; median of "
        f"{args.repeats} runs per setting, each in a fresh process"
    )
    cmd = f"python bench/bench_blas_threads.py --repeats {args.repeats} --out {args.out}"
    publish(args.out, MARK, cmd, head, rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
