"""The moving real car against its RTK reference: how good its Doppler velocity is, and where its
height goes wrong at the start (docs/fgo.md, "A moving car against RTK").

    .venv/bin/python bench/moving_car_rtk.py [--out docs/fgo.md]

1. Doppler velocity. The fusion links consecutive states with the mean of their two Doppler
   velocities (`FgoConfig.sigma_v`, chosen on simulated seeds and checked against static
   receivers, whose true velocity is zero). A moving car is checked here against the RTK
   reference's position differences, on the strictest epochs only: RTKLIB's forward and backward
   runs both fixed at both epochs and within 5 cm of each other (the difference of two such
   positions is good to a few cm/s). The static sets are beside it for comparison.
2. The drive's start, with the base (DGNSS). Heights of the first epochs (before RTK has a
   reference: a poor sky) and of the first reference epochs, for the node message's own fix,
   `non-cp`, `non-cp` without its robust kernel, `non-cp` with the paper's batch LM window
   instead of iSAM2 (the kernel's optimum, not an incremental solver's convergence), and
   `non-cp-ekf`.
Nothing here chooses a default.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
from docblock import publish
from real_data_regression import REAL, STATIC
from tune_real_data import static_velocity_errors

from coplane.evaluate.rtk_reference import RtkReference, rtk_reference
from coplane.evaluate.runner import run_method
from coplane.geo import ecef_to_geodetic, enu_rotation
from coplane.gtime import GpsTime
from coplane.messages import NodeMessage, SolutionMessage
from coplane.methods import get_method
from coplane.recording.reader import Recording, open_recording

CAR = "hk_klt_20210610_f9p_rover_hksc_base"
STRICT_M = 0.05  # forward and backward fixes at most this far apart
START_EPOCHS = 4  # first epochs of the drive shown, then the first reference epochs
FIRST_REFERENCE = 6


def node_messages(rec: Recording, dgnss: bool) -> dict[GpsTime, NodeMessage]:
    """The first vehicle's node messages by nominal epoch (`non-cp`'s run)."""
    vid = rec.manifest.vehicles[0].id
    out: dict[GpsTime, NodeMessage] = {}

    def keep(_sol: SolutionMessage, msgs: dict[str, NodeMessage]) -> None:
        m = msgs.get(vid)
        if m is not None:
            out[GpsTime(m.rx_time.week, m.rx_time.tow).round_to(rec.manifest.interval_s)] = m

    run_method(rec, "non-cp", dgnss=dgnss, vehicles=[vid], jobs=1, on_solution=keep)
    return out


def _row(name: str, e: np.ndarray) -> str:
    def f(x: np.ndarray) -> str:
        return " / ".join(f"{v:.3f}" for v in x)

    return f"| {name} | {len(e)} | {f(e.mean(axis=0))} | {f(np.sqrt(np.mean(e**2, axis=0)))} |"


def doppler_rows(rec: Recording, ref: RtkReference) -> list[str]:
    """2-epoch mean Doppler velocity error (ENU): the car on strict RTK pairs, the static sets."""
    msgs = node_messages(rec, dgnss=False)
    # both runs fixed within STRICT_M (< agree_m, so these are reference epochs too)
    strict = {t for t, apart in ref.both_fixed_m.items() if apart <= STRICT_M}
    errs = []
    for a in sorted(strict):
        b = a + rec.manifest.interval_s
        if b not in strict:
            continue
        va, vb = msgs.get(a), msgs.get(b)
        if va is None or vb is None or va.velocity is None or vb.velocity is None:
            continue
        r = enu_rotation(*ecef_to_geodetic(ref.positions[a])[:2])
        dop = 0.5 * (np.array(va.velocity.velocity_ecef_mps) + np.array(vb.velocity.velocity_ecef_mps))
        errs.append(r @ dop - r @ (ref.positions[b] - ref.positions[a]) / rec.manifest.interval_s)
    rows = [_row(f"`{CAR}`, moving car, strict RTK pairs", np.array(errs).reshape(-1, 3))]
    for folder, _, _ in STATIC:
        e = static_velocity_errors(folder)  # every epoch: consecutive pairs are 1 s apart
        rows.append(_row(f"`{folder}`, static, every epoch pair", (e[1:] + e[:-1]) / 2.0))
    return rows


def start_rows(rec: Recording, ref: RtkReference) -> list[str]:
    """Heights (m, ellipsoidal) at the drive's first epochs and at its first reference epochs."""
    vid = rec.manifest.vehicles[0].id
    msgs = node_messages(rec, dgnss=True)
    base = get_method("non-cp")
    assert base.fgo is not None
    methods = {
        "non-cp": base,
        "non-cp, no robust kernel": replace(base, fgo=replace(base.fgo, robust=None)),
        "non-cp, the paper's LM window": replace(base, fgo=replace(base.fgo, solver="lm-window")),
        "non-cp-ekf": get_method("non-cp-ekf"),
    }
    runs = {name: run_method(rec, spec, dgnss=True, vehicles=[vid], jobs=1) for name, spec in methods.items()}
    times = sorted(runs["non-cp"].positions[vid])
    shown = times[:START_EPOCHS] + sorted(ref.positions)[:FIRST_REFERENCE]

    def h(p: object) -> str:
        return "-" if p is None else f"{float(ecef_to_geodetic(np.asarray(p, dtype=float))[2]):.2f}"

    rows = []
    for t in shown:
        m = msgs.get(t)
        fix = m.spp.position_ecef_m if m is not None else None
        sats = sum(m.satellites.used) if m is not None else 0
        vdop = f"{m.spp.vdop:.1f}" if m is not None and m.spp.vdop is not None else "-"
        cells = " | ".join(h(r.positions[vid].get(t)) for r in runs.values())
        rows.append(
            f"| {t - times[0]:.0f} | {sats} / {vdop} | {h(ref.positions.get(t))} | {h(fix)} | {cells} |"
        )
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=None, help="write the two blocks into this page")
    args = ap.parse_args()
    command = ".venv/bin/python bench/moving_car_rtk.py " + " ".join(sys.argv[1:])
    rec = open_recording(REAL / CAR)
    ref = rtk_reference(rec)  # one RTKLIB run for both tables
    publish(
        args.out,
        "moving_car_doppler",
        command.strip(),
        "Node messages' Doppler velocity, the mean of two consecutive epochs as a Doppler link uses "
        f"it, against the truth: the moving car's RTK position differences where both RTK runs are "
        f"fixed at both epochs and within {STRICT_M * 100:.0f} cm, the static sets' zero.",
        [
            "| set | epoch pairs | mean E / N / U (m/s) | RMS E / N / U (m/s) |",
            "|---|---|---|---|",
            *doppler_rows(rec, ref),
        ],
    )
    publish(
        args.out,
        "moving_car_start",
        command.strip(),
        f"`{CAR}` with its base: the first {START_EPOCHS} epochs, before RTK gives a reference, then "
        f"the first {FIRST_REFERENCE} reference epochs. Ellipsoidal heights (m); the node message's "
        "fix is its own SPP with RAIM.",
        [
            "| s from start | satellites / VDOP | RTK reference | node message fix | non-cp "
            "| non-cp, no robust kernel | non-cp, the paper's LM window | non-cp-ekf |",
            "|---|---|---|---|---|---|---|---|",
            *start_rows(rec, ref),
        ],
    )


if __name__ == "__main__":
    main()
