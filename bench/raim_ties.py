"""How often the agent's RAIM meets a fault it cannot locate (docs/gnss-models.md, "Fault exclusion").

    .venv/bin/python bench/raim_ties.py [--out docs/gnss-models.md]

For the real recordings (../shared/data/real, `COPLANE_REAL_DATA`) and the bundled simulated one,
the agent's epoch solver (SPP with FDE, Doppler velocity) over every epoch, standalone and with
the recording's base (DGNSS) where it has one: how many
exclusions SPP and the Doppler solve made, and how many took more than one satellite because the
worst one's w-test was the same test as others' (`coplane.gnss.lsq.worst_rows`). Before
2026-11-30 rounding picked one satellite of such a group.
"""

from __future__ import annotations

import argparse
import collections
import os
from pathlib import Path

import numpy as np
from docblock import publish

import coplane
import coplane.gnss.doppler as doppler
import coplane.gnss.spp as spp
from coplane.evaluate.spp_run import run_spp
from coplane.gnss.lsq import worst_rows
from coplane.recording.reader import open_recording

REAL = Path(
    os.environ.get("COPLANE_REAL_DATA", Path(__file__).resolve().parents[2] / "shared" / "data" / "real")
)
SETS = {
    "HK TST, u-blox F9P, static urban": REAL / "urbannav_hk_tst_20200603_static_f9p",
    "HK KLT, u-blox F9P, moving car": REAL / "hk_klt_20210610_f9p_rover_hksc_base",
    "Nagoya, Septentrio, static": REAL / "matrtklib_nagoya_static_20240624",
    "bundled simulated urban loop (4 vehicles)": Path(coplane.__file__).parent
    / "data"
    / "recordings"
    / "default",
}
MARK = "raim_ties"


def count(path: Path, dgnss: bool) -> collections.Counter[str]:
    """Exclusions by solver and by how many rows each took. The solvers call `worst_rows` by
    name from their own modules, so a counting wrapper is put there for the run (a benchmark
    needs the count; the product has no use for it)."""
    seen: collections.Counter[str] = collections.Counter()

    def counted(kind: str):  # type: ignore[no-untyped-def]
        def wrapper(a: np.ndarray, v: np.ndarray, sigma: np.ndarray, rows: int | None = None) -> np.ndarray:
            group = worst_rows(a, v, sigma, rows)
            seen[kind] += 1
            seen[f"{kind} group"] += int(len(group) > 1)
            return group

        return wrapper

    spp.worst_rows, doppler.worst_rows = counted("spp"), counted("doppler")  # type: ignore[attr-defined]
    try:
        run_spp(open_recording(path), dgnss=dgnss)
    finally:
        spp.worst_rows, doppler.worst_rows = worst_rows, worst_rows  # type: ignore[attr-defined]
    return seen


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=None, help="write the table into this page's block")
    args = ap.parse_args()
    rows = [
        "| recording | mode | SPP exclusions | of them, several satellites | Doppler exclusions | of them, several satellites |",
        "|---|---|---|---|---|---|",
    ]
    for name, path in SETS.items():
        for dgnss in (False, True) if open_recording(path).manifest.base is not None else (False,):
            c = count(path, dgnss)
            mode = "DGNSS" if dgnss else "standalone"
            rows.append(
                f"| {name} | {mode} | {c['spp']} | {c['spp group']} | {c['doppler']} | {c['doppler group']} |"
            )
    head = "The agent's epoch solver, every epoch of every vehicle, without and with the recording's base."
    publish(args.out, MARK, ".venv/bin/python bench/raim_ties.py --out docs/gnss-models.md", head, rows)


if __name__ == "__main__":
    main()
