"""Read speed of coplane's RINEX observation reader vs georinex (and RTKLIB's C reader for scale).

Usage: .venv/bin/python bench/bench_rinex_read.py [--runs 3] [--out docs/performance-rinex.md]
Prints a Markdown table: median wall time of N runs per reader and file, and georinex / ours.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time
import warnings
from collections.abc import Callable
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
REAL = Path(os.environ.get("COPLANE_REAL_DATA", REPO.parent / "shared" / "data" / "real"))
FILES = [
    (
        "Nagoya rover, 3.04 Septentrio, 301 ep, 3.5 MB",
        REAL / "matrtklib_nagoya_static_20240624" / "rover.obs",
    ),
    (
        "HK TST, 3.02 u-blox F9P, CRLF, 986 ep, 3.7 MB",
        REAL / "urbannav_hk_tst_20200603_static_f9p" / "2020_06_03_TST_03.obs",
    ),
    (
        "GEONET 0759, 2.10 with splice records, 120 ep",
        REAL / "rtklib_geonet_0759_3040_20050402" / "07590920.05o",
    ),
]
GC_MEAS = ["C1C", "D1C", "S1C", "C2I", "D2I", "S2I", "C1I", "D1I", "S1I", "C1", "D1", "S1"]


def ours(path: Path) -> int:
    from coplane.recording.problems import Problems
    from coplane.recording.rinex_obs import read_obs

    return len(read_obs(path, Problems())[1])


def georinex_gc(path: Path) -> int:
    import georinex as gr

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return int(gr.load(path, use={"G", "C"}, meas=GC_MEAS).sizes["time"])


def georinex_all(path: Path) -> int:
    import georinex as gr

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return int(gr.load(path).sizes["time"])


def rtklib(path: Path) -> int:
    import pyrtklib as rt

    obs, nav, sta = rt.obs_t(), rt.nav_t(), rt.sta_t()
    if rt.readrnx(str(path), 1, "", obs, nav, sta) != 1:
        raise RuntimeError("readrnx failed")
    return int(obs.n)


READERS: list[tuple[str, Callable[[Path], int]]] = [
    ("coplane read_obs (G+C selected signals)", ours),
    ("georinex load(use=G,C, meas=selected)", georinex_gc),
    ("georinex load (everything)", georinex_all),
    ("RTKLIB readrnx via pyrtklib (C, all signals)", rtklib),
]


def median_time(fn: Callable[[Path], int], path: Path, runs: int) -> float | str:
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        try:
            fn(path)
        except Exception as exc:  # a reader that cannot parse the file is a result, not a crash
            return f"fails ({type(exc).__name__})"
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--out", type=Path, help="also write the table to this Markdown file")
    args = ap.parse_args()
    from importlib.metadata import version

    lines = [
        f"Median of {args.runs} runs, wall time in seconds; ratio = that reader's time / coplane's time.",
        f"Machine: {platform.machine()}, {os.cpu_count()} CPUs, Python {platform.python_version()}, "
        f"georinex {version('georinex')}, xarray {version('xarray')}, pyrtklib {version('pyrtklib')}.",
        "",
        "| file | reader | median s | ratio |",
        "|---|---|---:|---:|",
    ]
    for label, path in FILES:
        base: float | None = None
        for name, fn in READERS:
            t = median_time(fn, path, args.runs)
            if isinstance(t, str):
                lines.append(f"| {label} | {name} | {t} | - |")
                continue
            if base is None:
                base = t
            lines.append(f"| {label} | {name} | {t:.3f} | {t / base:.1f}x |")
    text = "\n".join(lines)
    print(text)
    if args.out:
        args.out.write_text(
            "# RINEX observation read speed\n\n"
            "Output of `.venv/bin/python bench/bench_rinex_read.py --out docs/performance-rinex.md`.\n"
            "coplane parses only the selected signal of GPS and BeiDou (what the estimator uses);\n"
            "georinex is shown both restricted to those signals and loading everything. On the RINEX 2.10\nGEONET file georinex 1.16.2 succeeds (1.16.1 failed on its splice records, see the data README)\nbut truncates epoch tags (30.0020000 s becomes 30.001 s).\n\n"
            + text
            + "\n"
        )


if __name__ == "__main__":
    main()
