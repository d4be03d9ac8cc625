"""SPP availability and accuracy on the real recordings (docs/spp-real-data.md is its output).

.venv/bin/python bench/spp_real_data.py > docs/spp-real-data.md
"""

from __future__ import annotations

import argparse
import datetime as dt
import os
from dataclasses import replace
from pathlib import Path

import numpy as np

from coplane.evaluate.metrics import accuracy
from coplane.evaluate.rtk_reference import rtk_reference
from coplane.evaluate.spp_run import run_spp
from coplane.gnss.epoch_solver import EpochSolverOptions
from coplane.gnss.spp import SppOptions
from coplane.recording.reader import open_recording

REAL = Path(
    os.environ.get("COPLANE_REAL_DATA", Path(__file__).resolve().parents[2] / "shared" / "data" / "real")
)
CASES = [
    ("matrtklib_nagoya_static_20240624", "standalone, FDE", False, "fde"),
    ("matrtklib_nagoya_static_20240624", "DGNSS (base 1 m away), FDE", True, "fde"),
    ("urbannav_hk_tst_20200603_static_f9p", "standalone, FDE", False, "fde"),
    ("urbannav_hk_tst_20200603_static_f9p", "standalone, no FDE", False, "off"),
    ("hk_klt_20210610_f9p_rover_hksc_base", "moving car, standalone, FDE", False, "fde"),
    ("hk_klt_20210610_f9p_rover_hksc_base", "moving car, DGNSS (CORS base), FDE", True, "fde"),
]
# no surveyed trajectory: RTKLIB's carrier-phase RTK is the truth where it gives one
RTK_TRUTH = {"hk_klt_20210610_f9p_rover_hksc_base"}


def main() -> None:
    argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    ).parse_args()
    print("# SPP on real data\n")
    print(
        f"Output of `bench/spp_real_data.py` ({dt.date.today()}). GPS L1 C/A + BeiDou B1I, 10 deg mask, "
        "broadcast Klobuchar (BDS coefficients for BeiDou) and Saastamoinen, C/N0-elevation weights, "
        "RAIM FDE (chi-square at 1e-3, w-test exclusion). Truth: the surveyed antenna positions; for the "
        "moving car, RTKLIB's carrier-phase RTK on the epochs where its forward and backward runs agree "
        "(`coplane.evaluate.rtk_reference`; the easier epochs of the drive, so its availability is "
        "of those). "
        "Agreement with RTKLIB pntpos under RTKLIB-equivalent options is tested in tests/gnss/test_spp_real.py.\n"
    )
    print(
        "| set | mode | epochs | availability | H RMSE m | V RMSE m | CEP95 m | max H m | max V m | most common no-fix reason |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    references = {f: rtk_reference(open_recording(REAL / f)).positions for f in RTK_TRUTH}
    for folder, mode, dgnss, raim in CASES:
        rec = open_recording(REAL / folder)
        opt = EpochSolverOptions()
        opt = replace(opt, spp=replace(SppOptions(), raim=raim))
        runs = run_spp(rec, dgnss=dgnss, options=opt)
        for vid, run in runs.items():
            truth = references.get(folder) or {t: np.asarray(p) for t, p in rec.truth_at(vid).items()}
            st = accuracy(run.fixes(), truth)
            why = run.no_solution.most_common(1)
            print(
                f"| {folder} | {mode} | {st.n_truth} | {100 * st.availability:.1f} % | {st.h_rmse_m:.2f} | "
                f"{st.v_rmse_m:.2f} | {st.cep95_m:.2f} | {st.h_max_m:.2f} | {st.v_max_m:.2f} | "
                f"{f'{why[0][0]} ({why[0][1]})' if why else '-'} |"
            )


if __name__ == "__main__":
    main()
