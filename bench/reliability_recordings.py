"""Corrupted-recording corpus (issue 13): `coplane spp` and `coplane eval` on every defect.

    .venv/bin/python bench/reliability_recordings.py     # about 2 minutes on 2 cores

Builds a clean simulated recording (urban-loop, 2 vehicles, 20 s, seed 7), applies each defect of
tests/support/corrupt_recordings.py to a copy, runs both commands with `--strict` in child
processes (wall time and peak RSS from wait4) and writes docs/reliability/recordings.md.
tests/recording/test_corrupt_corpus.py asserts the same rule on the same corpus.
"""

from __future__ import annotations

import argparse
import datetime as dt
import shutil
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from coplane.sim.generate import simulate

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))
from support.corrupt_recordings import DEFECTS, CorpusRun, make_corpus, run_one  # noqa: E402

OUT = REPO / "docs" / "reliability" / "recordings.md"
COMMANDS = ("spp", "eval")


def table(runs: list[CorpusRun], root: str) -> list[str]:
    """One row per run; the temporary corpus path is shortened to `<corpus>`."""
    what = {d.name: d.what for d in DEFECTS}
    lines = [
        "| defect | what | command | exit | wall s | peak RSS MB | rule | what the user sees (last line) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in runs:
        seen = r.last_line.replace(root, "<corpus>").replace("|", "/")
        lines.append(
            f"| {r.defect} | {what[r.defect]} | {r.command} | {r.exit_code} | {r.wall_s:.1f} "
            f"| {r.peak_rss_mb:.0f} | {'ok' if r.ok else '**FAILED**'} | {seen} |"
        )
    return lines


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=OUT)
    args = ap.parse_args()
    coplane = shutil.which("coplane") or str(Path(sys.executable).with_name("coplane"))
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        clean = simulate("urban-loop", root / "clean", vehicles=2, duration_s=20, seed=7)
        made = make_corpus(clean, root / "broken")
        jobs = [(c, d.name) for c in COMMANDS for d in DEFECTS]
        with ThreadPoolExecutor(2) as pool:
            runs = list(
                pool.map(
                    lambda j: run_one(coplane, j[0], j[1], made[j[1]], root / "out" / j[0] / j[1], True), jobs
                )
            )
    n_ok = sum(r.ok for r in runs)
    text = [
        "# Corrupted recordings",
        "",
        "Regenerate: `.venv/bin/python bench/reliability_recordings.py` "
        f"(run {dt.date.today().isoformat()}; {len(DEFECTS)} defects x {len(COMMANDS)} commands).",
        "",
        "Each recording is a clean simulated one (urban-loop, 2 vehicles, 20 s, seed 7) with one defect "
        "(`tests/support/corrupt_recordings.py`). Every command runs with `--strict` in its own process. "
        "The rule: no traceback, and either a non-zero exit whose message names the file, or a printed "
        "input-problem count. `--strict` exits with 3 when nothing was positioned or more than 5 % of the "
        "records had a problem; without it the same runs warn and exit 0.",
        "",
        f"- runs following the rule: **{n_ok} of {len(runs)}**; tracebacks: "
        f"**{sum(r.traceback for r in runs)}**",
        f"- slowest run: **{max(r.wall_s for r in runs):.1f} s** (limit 30 s); largest peak RSS: "
        f"**{max(r.peak_rss_mb for r in runs):.0f} MB** (limit 1024 MB)",
        "",
        *table(runs, str(root / "broken")),
        "",
    ]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text("\n".join(text))
    print("\n".join(text))
    print(f"wrote {args.out}")
    return 0 if n_ok == len(runs) else 1


if __name__ == "__main__":
    raise SystemExit(main())
