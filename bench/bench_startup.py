"""What a service process costs before its first message: import time and resident memory, at two
commits, measured in turn on the same machine.

    .venv/bin/python bench/bench_startup.py --base REV [--head HEAD] [--repeats 5]
        [--out docs/performance-scale.md [--block NAME]]

Every fusion server, agent, load generator and API process, and every `coplane` command, starts
by importing its modules; a server that joins a region set or restarts after `kill -9` pays it
before it can own a region, and its resident memory is the floor under the per-vehicle growth of
docs/performance-scale.md ("Memory over a long run"). For each service's entry module this
starts a fresh interpreter that imports it, and reports the import's wall time and the process's
peak RSS (`ru_maxrss`) and whether scipy.stats got loaded (an agent and the load generator
also load the standstill test's modules, as they do when they start), alternating the two
commits (base, head, base, head, ...) so that the host's drift falls on both; medians of
`--repeats` runs.

Each side's code is `git archive` of its commit, unpacked and put first on PYTHONPATH
(`bench_scale_ab.unpack`): uncommitted edits are in neither side.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from bench_scale_ab import check_imports, environment, unpack  # bench/ is first on sys.path
from docblock import machine, publish

PY = sys.executable
MARK = "bench_startup"
# each service's entry module: what `python -m coplane.<service>` imports before it runs; an
# agent and the load generator also load the standstill test's modules when they start
# (`coplane.gnss.standstill.load_dependencies`, absent from commits before it)
PRELOAD = """
try:
    from coplane.gnss.standstill import load_dependencies
except ImportError:
    pass
else:
    load_dependencies()
"""
MODULES = [
    ("fusion server", "coplane.fusion_server.server", ""),
    ("vehicle agent", "coplane.vehicle_agent.agent", PRELOAD),
    ("load generator", "coplane.vehicle_agent.loadgen", PRELOAD),
    ("API", "coplane.api.app", ""),
    ("`coplane` command line", "coplane.cli", ""),
]
PROBE = """
import json, resource, sys, time
t0 = time.perf_counter()
import {module}
{then}
t = time.perf_counter() - t0
rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
print(json.dumps({{"s": t, "mb": rss, "stats": "scipy.stats" in sys.modules}}))
"""


def measure(module: str, then: str, env: dict[str, str]) -> dict[str, float]:
    """One fresh interpreter importing `module` and running `then`: seconds, peak RSS in MB,
    scipy.stats loaded."""
    code = PROBE.format(module=module, then=then)
    out = subprocess.run([PY, "-c", code], env=env, check=True, capture_output=True, text=True).stdout
    return dict(json.loads(out.strip().splitlines()[-1]))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--base", required=True)
    ap.add_argument("--head", default="HEAD")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--block", default=MARK)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="coplane-startup-") as tmp:
        sides = [unpack(rev, Path(tmp)) for rev in (args.base, args.head)]
        envs = {short: environment(path) for short, path in sides}
        for short, path in sides:
            check_imports(short, envs[short], path)
        runs: dict[tuple[str, str], list[dict[str, float]]] = {}
        for _ in range(args.repeats):
            for _, module, then in MODULES:
                for short, _ in sides:  # alternating, module by module
                    runs.setdefault((short, module), []).append(measure(module, then, envs[short]))
    (base, _), (head, _) = sides
    rows = [
        f"| process | import s, {base} | import s, {head} | {head} / {base} "
        f"| peak RSS MB, {base} | peak RSS MB, {head} | scipy.stats loaded, {base} / {head} |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, module, _ in MODULES:
        b, h = runs[(base, module)], runs[(head, module)]
        bs, hs = statistics.median(r["s"] for r in b), statistics.median(r["s"] for r in h)
        bm, hm = statistics.median(r["mb"] for r in b), statistics.median(r["mb"] for r in h)
        loaded = f"{'yes' if b[0]['stats'] else 'no'} / {'yes' if h[0]['stats'] else 'no'}"
        rows.append(
            f"| {name} (`{module}`) | {bs:.2f} | {hs:.2f} | {hs / bs:.2f} | {bm:.0f} | {hm:.0f} | {loaded} |"
        )
    head_line = (
        f"machine: {machine()}; a fresh interpreter per import, the commits alternating, "
        f"median of {args.repeats} runs each"
    )
    cmd = (
        f"python bench/bench_startup.py --base {args.base} --head {args.head} --repeats {args.repeats}"
        + (f" --block {args.block}" if args.block != MARK else "")
        + f" --out {args.out}"
    )
    publish(args.out, args.block, cmd, head_line, rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
