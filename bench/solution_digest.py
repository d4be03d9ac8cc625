"""Fingerprint every method's positions and covariances on the bundled recording, bit for bit.

For behaviour-preserving changes: run it on two checkouts and compare the digests. It uses only
`open_recording` and `run_method`, which every version since the speed work has, so an older
checkout can be fingerprinted with this script by putting that checkout's library first:

    PYTHONPATH=/path/to/old/shared .venv/bin/python bench/solution_digest.py old.json
    .venv/bin/python bench/solution_digest.py new.json
    diff old.json new.json && echo identical

Each digest is sha256 over (vehicle, week, tow, position float64 bytes, covariance float64 bytes)
in sorted order; "pc@0.4" is pc at 40 % ranging interruption.

`--city N` fingerprints a simulated city of N vehicles instead (`coplane simulate --scenario city
--vehicles N --duration 20 --seed 11`, made by the library being fingerprinted; default method
`pc`): the per-vehicle paths a fusion server runs for hundreds of vehicles, with cluster splits
and merges the 4-vehicle recording never has.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import coplane
from coplane.evaluate.runner import run_method
from coplane.recording.reader import open_recording

DEFAULT = [
    "non-cp", "mci", "pc", "pc@0.4", "pc-no-ir", "pc-no-ir-no-fe", "pc-self",
    "non-cp-ekf", "dd-cp", "gamp-cp", "gamp-cp@0.6",
]  # fmt: skip


BUNDLED = Path(coplane.__file__).parent / "data" / "recordings" / "default"


def digest(method: str, interruption: float, recording: Path = BUNDLED) -> str:
    rec = open_recording(recording)
    run = run_method(rec, method, interruption=interruption)
    h = hashlib.sha256()
    for vid in sorted(run.positions):
        for t in sorted(run.positions[vid]):
            h.update(f"{vid} {t.week} {t.tow!r} ".encode())
            h.update(run.positions[vid][t].tobytes())
            c = run.covariances.get(vid, {}).get(t)
            if c is not None:
                h.update(c.tobytes())
    return h.hexdigest()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path, help="JSON file: method -> sha256")
    ap.add_argument("methods", nargs="*", help="method[@rate] (default: all; with --city, pc)")
    ap.add_argument("--city", type=int, default=0, help="a simulated city of this many vehicles")
    args = ap.parse_args()
    out = {}
    with tempfile.TemporaryDirectory(prefix="coplane-digest-") as tmp:
        recording, methods = BUNDLED, args.methods or DEFAULT
        if args.city:
            recording, methods = Path(tmp) / "city", args.methods or ["pc"]
            cmd = [sys.executable, "-m", "coplane.cli", "simulate", "--scenario", "city", "--vehicles",
                   str(args.city), "--duration", "20", "--seed", "11", "--out", str(recording)]  # fmt: skip
            subprocess.run(cmd, check=True, capture_output=True)
        for arg in methods:
            name, _, rate = arg.partition("@")
            out[arg] = digest(name, float(rate or 0.0), recording)
            print(f"{arg:16s} {out[arg]}", flush=True)
    args.out.write_text(json.dumps(out, indent=1) + "\n")
    print(f"library: {Path(coplane.__file__).parent}")


if __name__ == "__main__":
    main()
