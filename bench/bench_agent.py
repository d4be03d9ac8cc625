"""A vehicle agent's GNSS front end against RTKLIB's SPP on the same data (issue 16, "Agent cost").

    .venv/bin/python bench/bench_agent.py [--runs 3] [--out docs/performance-agent.md]

For each recording (the bundled simulated fleet and the real static sets), measured in the same
run, median of `--runs`:
- RTKLIB 2.4.3 `postpos` through pyrtklib: single-point positioning with RAIM FDE (GPS + BeiDou,
  broadcast ephemeris, Klobuchar, Saastamoinen), each vehicle's RINEX file read and solved;
- coplane `run_spp`: our SPP with FDE on the same epochs (the file read before, as RTKLIB's is
  not);
- coplane agent front end: what a vehicle agent does per epoch before the bus (`VehicleStep`:
  SPP with FDE, Doppler velocity, the per-satellite factor inputs, the node message and its wire
  encoding), method `non-cp` (no plane fit: that depends on the fleet), standalone and, where
  the recording has a base, with DGNSS as the fleet runs;
- whole process: `coplane spp` (the command: imports, reading, solving, the .pos file) against a
  Python process that runs coplane's RTKLIB row (`postpos` on the same files; it imports
  coplane's evaluation package too, for RTKLIB's options, so both pay the same start-up).
Times are per vehicle-epoch of the RINEX files (RTKLIB's too, whether it output a solution or not);
ratio = coplane / RTKLIB of the same run.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
REAL = Path(os.environ.get("COPLANE_REAL_DATA", REPO.parent / "shared" / "data" / "real"))
RECORDINGS = [
    ("bundled simulated fleet (4 vehicles x 600 ep.)", REPO / "shared/coplane/data/recordings/default"),
    ("Nagoya, Septentrio, static (301 ep.)", REAL / "matrtklib_nagoya_static_20240624"),
    ("HK TST, u-blox F9P, static urban (986 ep.)", REAL / "urbannav_hk_tst_20200603_static_f9p"),
]

# the RTKLIB process of the whole-process row: coplane's RTKLIB row, standalone
RTKLIB_PROCESS = """
import sys
from coplane.evaluate.rtklib_row import process_recording
from coplane.recording.reader import open_recording
res = process_recording(open_recording(sys.argv[1]), dgnss=False)
print(sum(len(p) for p in res.run.positions.values()))
"""


def rtklib_compute(rec_path: Path) -> tuple[float, int]:
    """Seconds inside RTKLIB's postpos (its reading included) and the epochs it output."""
    from coplane.evaluate.rtklib_row import process_recording
    from coplane.recording.reader import open_recording

    res = process_recording(open_recording(rec_path), dgnss=False)
    return sum(res.run.solve_times_s), sum(len(p) for p in res.run.positions.values())


def coplane_spp(rec_path: Path) -> tuple[float, int]:
    """Seconds in our SPP with FDE over every vehicle-epoch, and how many."""
    from coplane.evaluate.spp_run import run_spp
    from coplane.recording.reader import open_recording

    rec = open_recording(rec_path)
    rec.fleet_epochs()  # read before the clock starts
    t0 = time.perf_counter()
    runs = run_spp(rec, dgnss=False)
    return time.perf_counter() - t0, sum(r.n_epochs for r in runs.values())


def coplane_front_end(rec_path: Path, dgnss: bool) -> tuple[float, int]:
    """Seconds in the agent's per-epoch work up to the encoded node message, and how many."""
    from coplane.bus import encode
    from coplane.evaluate.runner import lockstep_schedule
    from coplane.recording.reader import open_recording
    from coplane.replay import BaseCorrections, replay_setup

    rec = open_recording(rec_path)
    setup = replay_setup(rec.manifest, "non-cp", dgnss=dgnss)
    ids = [v.id for v in rec.manifest.vehicles]
    steps = {vid: setup.vehicle_step(rec, vid) for vid in ids}
    schedule = lockstep_schedule(rec, ids)
    base = BaseCorrections.of(rec, setup.use_dgnss)
    n = 0
    t0 = time.perf_counter()
    for t, live in schedule:
        corr = base.at(t)
        for vid, ep in live.items():
            if ep is None:
                continue
            encode(steps[vid].process(t, ep, corr))
            n += 1
    return time.perf_counter() - t0, n


def whole_process(args: list[str]) -> float:
    """Wall seconds of a fresh Python process."""
    t0 = time.perf_counter()
    subprocess.run([sys.executable, *args], check=True, capture_output=True, cwd=REPO)
    return time.perf_counter() - t0


def median_of(runs: int, fn, *a) -> tuple[float, int]:  # type: ignore[no-untyped-def]
    """Median seconds of `runs` calls and the count the calls return (the same each time)."""
    out = [fn(*a) for _ in range(runs)]
    return statistics.median(s for s, _ in out), out[0][1]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    import pyrtklib  # noqa: F401  (fail early: the comparison needs it)

    from coplane.recording.reader import open_recording

    lines = [
        "# Performance: a vehicle agent's GNSS front end against RTKLIB\n",
        f"Output of `.venv/bin/python bench/bench_agent.py --runs {args.runs} --out docs/performance-agent.md` "
        f"({time.strftime('%Y-%m-%d')}). Machine: {platform.machine()}, {os.cpu_count()} CPUs, Python "
        f"{platform.python_version()}. What each row measures is in the script's docstring; medians of "
        f"{args.runs} runs, one process, nothing else running. ms per vehicle-epoch; ratio = coplane / "
        "RTKLIB's SPP of the same run (issue 16 asks for the front end within 3x).\n",
        "| recording | what | vehicle-epochs | ms / vehicle-epoch | ratio to RTKLIB |",
        "|---|---|---:|---:|---:|",
    ]
    print("\n".join(lines), flush=True)
    for label, path in RECORDINGS:
        if not (path / "fleet.toml").exists():
            print(f"skipped {label}: {path} has no fleet.toml", file=sys.stderr)
            continue
        has_base = open_recording(path).manifest.base is not None
        rtk_s, rtk_n = median_of(args.runs, rtklib_compute, path)
        s, n = median_of(args.runs, coplane_spp, path)
        # per epoch of the files, for both: RTKLIB works on every epoch, solved or not
        ref = 1e3 * rtk_s / n
        rows = [(f"RTKLIB postpos, single, RAIM FDE ({rtk_n} solutions)", n, ref)]
        rows.append(("coplane SPP with FDE", n, 1e3 * s / n))
        s, n = median_of(args.runs, coplane_front_end, path, False)
        rows.append(("coplane agent front end, standalone", n, 1e3 * s / n))
        if has_base:
            s, n = median_of(args.runs, coplane_front_end, path, True)
            rows.append(("coplane agent front end, DGNSS", n, 1e3 * s / n))
        with tempfile.TemporaryDirectory() as tmp:
            pos = str(Path(tmp) / "out.pos")
            ours = statistics.median(
                whole_process(["-m", "coplane.cli", "spp", str(path), "--out", pos]) for _ in range(args.runs)
            )
        theirs = statistics.median(whole_process(["-c", RTKLIB_PROCESS, str(path)]) for _ in range(args.runs))
        for what, n, ms in rows:
            lines.append(f"| {label} | {what} | {n} | {ms:.3f} | {ms / ref:.2f} |")
            print(lines[-1], flush=True)
        lines.append(
            f"| {label} | whole process: `coplane spp` {ours:.2f} s, RTKLIB process {theirs:.2f} s | | | "
            f"{ours / theirs:.2f} |"
        )
        print(lines[-1], flush=True)
    if args.out is not None:
        args.out.write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
