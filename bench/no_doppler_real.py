"""The real moving car without Doppler: the Kowloon Tong F9P drive with its Doppler observations
taken out of the rover's RINEX, against RTKLIB's RTK reference (docs/fgo.md, "Receivers without
Doppler").

    .venv/bin/python bench/no_doppler_real.py [--out docs/fgo.md]

A receiver or stream without Doppler (an RTCM MSM4 stream, a pseudorange-only log) leaves the
factor graph's motion link with the velocity between its last two estimates
(`FgoConfig.no_doppler_velocity`). The simulator shares its models with the library, so the
choice made on simulated drives is checked here on a real receiver: the same drive, the same
pseudoranges, carrier phases and C/N0, only the `D` columns removed (the base station keeps its
own, which DGNSS does not use). The RTK reference is RTKLIB's, made from the carrier phases,
which are untouched. Rows: `non-cp` with the settings before receivers without Doppler had their
own (the 3-D difference, no covariance), each share of the estimates' covariance, each sigma of
the height's link (`FgoConfig.no_doppler_sigma_up`; 0.2 m/s, the Doppler receivers' outage value,
until 2026-12-02), and the EKF. Nothing here chooses a default.
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
from dataclasses import replace
from pathlib import Path

from docblock import publish
from real_data_regression import REAL

from coplane.evaluate.metrics import accuracy
from coplane.evaluate.rtk_reference import use_rtk_truth
from coplane.evaluate.runner import run_method
from coplane.methods import get_method
from coplane.recording.reader import open_recording

CAR = "hk_klt_20210610_f9p_rover_hksc_base"
SHARES = (0.1, 0.25, 0.5, 1.0)
SIGMAS_UP = (0.2, 0.3, 0.4, 0.5)  # FgoConfig.no_doppler_sigma_up, m/s
LABEL = "SYS / # / OBS TYPES"


def without_doppler(text: str) -> str:
    """RINEX 3 observations with every Doppler (`D..`) type and its column taken out. Headers may
    list a system's types over continuation lines; each data line is the satellite and 16-column
    fields in the header's order.

    A text edit, not coplane's reader and writer: the writer keeps the one signal per system the
    estimators use, and RTKLIB's RTK reference needs the file's L2 phases as they are."""
    lines = text.splitlines()
    end = next(i for i, line in enumerate(lines) if "END OF HEADER" in line[60:])
    types: dict[str, list[str]] = {}
    header: list[str] = []
    current = ""
    for line in lines[:end]:
        if line[60:].strip() != LABEL:
            header.append(line)
            continue
        if line[0] != " ":
            current = line[0]
            types[current] = []
        types[current] += line[7:60].split()
    for sys, codes in types.items():  # written back, 13 types per line
        kept = [c for c in codes if c[0] != "D"]
        chunks = [kept[i : i + 13] for i in range(0, len(kept), 13)] or [[]]
        for k, chunk in enumerate(chunks):
            head = f"{sys}  {len(kept):3d}" if k == 0 else " " * 6
            header.append((head + "".join(f" {c:3}" for c in chunk)).ljust(60) + LABEL)
    out = [*header, lines[end]]
    for line in lines[end + 1 :]:
        if not line or line[0] == ">" or line[0] not in types:
            out.append(line)
            continue
        fields = [line[3 + 16 * i : 3 + 16 * (i + 1)].ljust(16) for i in range(len(types[line[0]]))]
        kept = [f for c, f in zip(types[line[0]], fields, strict=True) if c[0] != "D"]
        out.append((line[:3] + "".join(kept)).rstrip())
    return "\n".join(out) + "\n"


def copy_without_doppler(src: Path, dst: Path, obs: str) -> Path:
    """The recording `src` copied to `dst` with `obs` (the rover's file) without Doppler."""
    shutil.copytree(src, dst)
    path = dst / obs
    path.write_text(without_doppler(path.read_text(encoding="ascii", errors="replace")), encoding="ascii")
    return dst


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    src = open_recording(REAL / CAR)
    rover = src.manifest.vehicles[0]
    obs = Path(rover.obs).relative_to(src.manifest.root) if Path(rover.obs).is_absolute() else Path(rover.obs)
    with tempfile.TemporaryDirectory() as tmp:
        rec = open_recording(copy_without_doppler(REAL / CAR, Path(tmp) / CAR, str(obs)))
        note = use_rtk_truth(rec)
        vid = rover.id
        base = get_method("non-cp")
        assert base.fgo is not None
        runs = [
            (
                "non-cp, before (3-D difference, no covariance, height sigma 0.2 m/s)",
                replace(
                    base,
                    fgo=replace(
                        base.fgo,
                        no_doppler_velocity="estimates",
                        no_doppler_velocity_covariance=0.0,
                        no_doppler_sigma_up=None,  # the outage value, motion_sigma_up
                    ),
                ),
            )
        ]
        for share in SHARES:
            cfg = replace(base.fgo, no_doppler_velocity="horizontal", no_doppler_velocity_covariance=share)
            mark = " (default)" if cfg == base.fgo else ""
            runs.append((f"non-cp, horizontal, covariance share {share:g}{mark}", replace(base, fgo=cfg)))
        for up in SIGMAS_UP:
            cfg = replace(base.fgo, no_doppler_sigma_up=up)
            mark = " (default)" if cfg == base.fgo else " (before 2026-12-02)" if up == 0.2 else ""
            runs.append((f"non-cp, height sigma {up:g} m/s{mark}", replace(base, fgo=cfg)))
        runs.append(("non-cp-ekf", get_method("non-cp-ekf")))
        rows = [
            "| run | H RMSE (m) | V RMSE (m) | H max (m) | V max (m) | epochs |",
            "|---|---|---|---|---|---|",
        ]
        for label, spec in runs:
            run = run_method(rec, spec, vehicles=[vid])
            st = accuracy(run.positions[vid], rec.truth_at(vid))
            rows.append(
                f"| {label} | {st.h_rmse_m:.2f} | {st.v_rmse_m:.2f} | {st.h_max_m:.2f} | {st.v_max_m:.2f} | {st.n_solved} |"
            )
    head = (
        f"`{CAR}` with its base, the rover's Doppler removed; errors on the RTK reference's epochs ({note})."
    )
    publish(args.out, "no_doppler_real", "python bench/no_doppler_real.py --out docs/fgo.md", head, rows)


if __name__ == "__main__":
    main()
