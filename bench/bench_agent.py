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
  the recording has a base, with DGNSS as the fleet runs (the base's own epoch included, as an
  agent computes its corrections from the base's observations); with several vehicles also
  each vehicle alone (its epochs in turn, sharing no orbit evaluation with the others, as an
  agent process with one receiver), since interleaved in one process they share them;
- RTKLIB postpos in DGPS mode on the same rover and base files, where the recording has a base:
  the like-for-like reference of the DGNSS front end, which also processes the base's epochs;
- whole process: `coplane spp` (the command: imports, reading, solving, the .pos file) against a
  Python process that runs coplane's RTKLIB row (`postpos` on the same files; it imports
  coplane's evaluation package too, for RTKLIB's options, so both pay the same start-up).
Times are per vehicle-epoch of the RINEX files (RTKLIB's too, whether it output a solution or not).
The rows run in rounds, each round every row once in turn, and a ratio = coplane / RTKLIB is taken
within a round (the DGNSS front end against RTKLIB's DGPS, every other row against RTKLIB's
single-point run): this VM's speed drifts by tens of percent between minutes, so ratios of medians
taken minutes apart moved by as much (issue 16 reviews, 2026-11-28).
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


def rtklib_compute(rec_path: Path, dgnss: bool = False) -> tuple[float, int]:
    """Seconds inside RTKLIB's postpos (its reading included) and the epochs it output."""
    from coplane.evaluate.rtklib_row import process_recording
    from coplane.recording.reader import open_recording

    res = process_recording(open_recording(rec_path), dgnss=dgnss)
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


def coplane_front_end(rec_path: Path, dgnss: bool, alone: bool = False) -> tuple[float, int]:
    """Seconds in the agent's per-epoch work up to the encoded node message, and how many.

    The vehicles run interleaved in one process, as `coplane loadgen` runs them, so they share
    each orbit evaluation (`ephemeris.slotted_state`); `alone`: each vehicle's epochs in turn
    with those shared states forgotten first, as an agent process with one receiver runs them.
    """
    from coplane.bus import encode
    from coplane.evaluate.runner import lockstep_schedule
    from coplane.gnss.ephemeris import clear_caches
    from coplane.recording.reader import open_recording
    from coplane.replay import BaseCorrections, replay_setup

    rec = open_recording(rec_path)
    setup = replay_setup(rec.manifest, "non-cp", dgnss=dgnss)
    ids = [v.id for v in rec.manifest.vehicles]
    steps = {vid: setup.vehicle_step(rec, vid) for vid in ids}
    schedule = list(lockstep_schedule(rec, ids))
    base = BaseCorrections.of(rec, setup.use_dgnss)
    passes = [[(t, {vid: live.get(vid)}) for t, live in schedule] for vid in ids] if alone else [schedule]
    n = 0
    elapsed = 0.0
    for one_pass in passes:
        if alone:
            clear_caches()
        t0 = time.perf_counter()
        for t, live in one_pass:
            corr = base.at(t)
            for vid, ep in live.items():
                if ep is None:
                    continue
                encode(steps[vid].process(t, ep, corr))
                n += 1
        elapsed += time.perf_counter() - t0
    return elapsed, n


def whole_process(args: list[str]) -> tuple[float, int]:
    """Wall seconds of a fresh Python process (and 0, the shape of the other measurements)."""
    t0 = time.perf_counter()
    subprocess.run([sys.executable, *args], check=True, capture_output=True, cwd=REPO)
    return time.perf_counter() - t0, 0


def interleaved(runs: int, jobs: dict[str, tuple]) -> dict[str, list[tuple[float, int]]]:  # type: ignore[type-arg]
    """Each job `runs` times, in turn (job A, B, C, then A, B, C again...), so every round sees the
    same host: a ratio is taken within a round, and this shared VM's speed drifts between rounds."""
    out: dict[str, list[tuple[float, int]]] = {k: [] for k in jobs}
    for _ in range(runs):
        for k, (fn, *a) in jobs.items():
            out[k].append(fn(*a))
    return out


def ms_per_epoch(res: list[tuple[float, int]], n: int) -> list[float]:
    """Milliseconds per vehicle-epoch of each run (RTKLIB's too per epoch of the files, solved or not)."""
    return [1e3 * s / n for s, _ in res]


def _ratios(ratios: list[float]) -> str:
    """The median ratio and the rounds' range, as two table cells."""
    return f"{statistics.median(ratios):.2f} | {min(ratios):.2f} - {max(ratios):.2f}"


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
        f"{platform.python_version()}. What each row measures is in the script's docstring; {args.runs} "
        "rounds, each running every row once in turn, one process, nothing else running. ms per "
        "vehicle-epoch, median of the rounds; ratio = coplane / RTKLIB's SPP in the same mode (single-point, "
        "or DGPS for the DGNSS front end), taken within each round, median of the rounds (issue 16 asks "
        "for the front end within 3x), and its lowest and highest round.\n",
        "| recording | what | vehicle-epochs | ms / vehicle-epoch | ratio to RTKLIB | lowest - highest round |",
        "|---|---|---:|---:|---:|---:|",
    ]
    print("\n".join(lines), flush=True)
    for label, path in RECORDINGS:
        if not (path / "fleet.toml").exists():
            print(f"skipped {label}: {path} has no fleet.toml", file=sys.stderr)
            continue
        has_base = open_recording(path).manifest.base is not None
        jobs = {
            "rtk": (rtklib_compute, path),
            "spp": (coplane_spp, path),
            "fe": (coplane_front_end, path, False),
        }
        several = len(open_recording(path).manifest.vehicles) > 1
        if several:
            jobs["fe-alone"] = (coplane_front_end, path, False, True)
        if has_base:
            jobs |= {"rtk-dg": (rtklib_compute, path, True), "fe-dg": (coplane_front_end, path, True)}
        res = interleaved(args.runs, jobs)
        n = res["spp"][0][1]  # the vehicle-epochs of the files
        ms = {k: ms_per_epoch(v, n) for k, v in res.items()}
        # (what, ms per vehicle-epoch, the RTKLIB run it is compared with, round by round)
        table = [
            (f"RTKLIB postpos, single, RAIM FDE ({res['rtk'][0][1]} solutions)", "rtk", "rtk"),
            ("coplane SPP with FDE", "spp", "rtk"),
            ("coplane agent front end, standalone", "fe", "rtk"),
        ]
        if several:
            table.append(("coplane agent front end, standalone, each vehicle alone", "fe-alone", "rtk"))
        if has_base:
            table += [
                (f"RTKLIB postpos, DGPS, RAIM FDE ({res['rtk-dg'][0][1]} solutions)", "rtk-dg", "rtk-dg"),
                ("coplane agent front end, DGNSS (ratio to RTKLIB DGPS)", "fe-dg", "rtk-dg"),
            ]
        rows = [
            (what, n, statistics.median(ms[k]), [a / b for a, b in zip(ms[k], ms[ref], strict=True)])
            for what, k, ref in table
        ]
        with tempfile.TemporaryDirectory() as tmp:
            pos = str(Path(tmp) / "out.pos")
            procs = interleaved(
                args.runs,
                {
                    "ours": (whole_process, ["-m", "coplane.cli", "spp", str(path), "--out", pos]),
                    "theirs": (whole_process, ["-c", RTKLIB_PROCESS, str(path)]),
                },
            )
        ours = statistics.median(s for s, _ in procs["ours"])
        theirs = statistics.median(s for s, _ in procs["theirs"])
        proc_ratios = [a / b for (a, _), (b, _) in zip(procs["ours"], procs["theirs"], strict=True)]
        for what, n_ep, ms_ep, ratios in rows:
            lines.append(f"| {label} | {what} | {n_ep} | {ms_ep:.3f} | {_ratios(ratios)} |")
            print(lines[-1], flush=True)
        lines.append(
            f"| {label} | whole process: `coplane spp` {ours:.2f} s, RTKLIB process {theirs:.2f} s | | | "
            f"{_ratios(proc_ratios)} |"
        )
        print(lines[-1], flush=True)
    if args.out is not None:
        args.out.write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
