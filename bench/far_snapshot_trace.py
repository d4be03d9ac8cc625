"""One vehicle through a deep canyon of a simulated city: what the FDE does when most of an epoch
is NLOS, and where the track goes (docs/fgo.md, "A right prediction against a far snapshot").

    .venv/bin/python bench/far_snapshot_trace.py [--scenario city] [--seed 1202] [--vehicle u3]
        [--start 150] [--end 162] [--limit 50] [--dead-reckon] [--block far_snapshot_trace]
        [--out docs/fgo.md]

The recording is `coplane simulate` (4 vehicles, 200 s): by default the city of an exploration
seed (`coplane.evaluate.benchmark.EXPLORATION`, never reported), where the rule was found; the
docs also show the retired held-out seed that vetoed it (urban-loop 903, u2, 70-82 s). `non-cp`
runs on that vehicle alone, once with the FDE's snapshot always believed (the default) and once
with `fde_snapshot_max_chi2` = `--limit`; per epoch the table has the node message's own fix and
Doppler, the FDE's verdict, the snapshot fit's squared Mahalanobis distance from the prediction
and the horizontal error of both runs against the simulator's truth. Nothing here chooses a
default.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
from pathlib import Path

import numpy as np
from docblock import publish

import coplane.fgo.prepare as prepare
from coplane.evaluate.benchmark import make_recordings
from coplane.evaluate.runner import run_method
from coplane.geo import ecef_to_geodetic, enu_rotation
from coplane.gtime import GpsTime
from coplane.messages import NodeMessage, SolutionMessage
from coplane.methods import get_method
from coplane.recording.reader import Recording

MARK = "far_snapshot_trace"


def trace(
    rec: Recording, vid: str, limit: float | None, dead_reckon: bool = False
) -> dict[float, dict[str, object]]:
    """Per second since the vehicle's first truth epoch: the node message's own fix and Doppler,
    the FDE's verdict, the snapshot fit's squared Mahalanobis distance from the prediction (where
    the prediction was rejected) and the horizontal error; `limit` is `fde_snapshot_max_chi2`,
    `dead_reckon` `fde_snapshot_dead_reckon`."""
    spec = get_method("non-cp")
    assert spec.fgo is not None
    fgo = dataclasses.replace(spec.fgo, fde_snapshot_max_chi2=limit, fde_snapshot_dead_reckon=dead_reckon)
    spec = dataclasses.replace(spec, fgo=fgo)
    truth = {t: np.asarray(p) for t, p in rec.truth_at(vid).items()}
    t0 = min(truth)
    rows: dict[float, dict[str, object]] = {}
    pending: dict[str, object] = {}
    screen, distance2 = prepare.screen, prepare.snapshot_distance2

    def watched(prs, predicted, last_cov, link_sigma, cfg, stats, young=False, may_restart=False):  # type: ignore[no-untyped-def]
        before = dict(stats.rejected)
        kept, w, restart = screen(prs, predicted, last_cov, link_sigma, cfg, stats, young, may_restart)
        new = {k for k, n in stats.rejected.items() if n != before.get(k, 0)}
        verdict = f"{len(kept)} of {len(prs)} kept"
        if "fde_dead_reckoned" in new:
            verdict = "rejected, snapshot disbelieved, dead-reckoned: " + verdict
        elif restart is not None and may_restart:
            verdict = "rejected, track restarts: " + verdict
        elif "fde_snapshot_disbelieved" in new:
            verdict = "rejected, snapshot disbelieved: " + verdict
        elif "fde_prediction_rejected" in new:
            verdict = "rejected, snapshot: " + verdict
        pending["fde"] = verdict
        return kept, w, restart

    def measured(res, p_pred):  # type: ignore[no-untyped-def]
        d2 = distance2(res, p_pred)
        if d2 is not None:
            pending.setdefault("chi2", d2)
        return d2

    def keep(sol: SolutionMessage, msgs: dict[str, NodeMessage]) -> None:
        t = GpsTime(sol.epoch.week, sol.epoch.tow)
        m = msgs.get(vid)
        est = next((v for v in sol.vehicles if v.vehicle_id == vid), None)
        if est is not None and m is not None and t in truth:
            r = enu_rotation(*ecef_to_geodetic(truth[t])[:2])
            e = r @ (np.asarray(est.position_ecef_m) - truth[t])
            rows[t - t0] = {"fix": m.spp.ok, "doppler": m.velocity is not None, "fde": pending.get("fde", "-"),
                            "chi2": pending.get("chi2"), "h": float(np.hypot(e[0], e[1]))}  # fmt: skip
        pending.clear()

    prepare.screen, prepare.snapshot_distance2 = watched, measured  # type: ignore[assignment]
    try:
        run_method(rec, spec, vehicles=[vid], jobs=1, on_solution=keep)
    finally:
        prepare.screen, prepare.snapshot_distance2 = screen, distance2
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", default="city")
    ap.add_argument("--seed", type=int, default=1202)
    ap.add_argument("--vehicle", default="u3")
    ap.add_argument("--start", type=float, default=150.0)
    ap.add_argument("--end", type=float, default=162.0)
    ap.add_argument("--limit", type=float, default=50.0, help="fde_snapshot_max_chi2 of the second run")
    ap.add_argument(
        "--dead-reckon", action="store_true", help="the second run also with fde_snapshot_dead_reckon"
    )
    ap.add_argument("--block", default=MARK, help="the docs block to write")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        rec = make_recordings(args.scenario, [args.seed], Path(tmp), 4, 200.0)[0]
        old = trace(rec, args.vehicle, None)
        new = trace(rec, args.vehicle, args.limit, args.dead_reckon)
    rows = [
        "| s | node fix / Doppler | FDE, snapshot always believed | snapshot chi2 | H error (m) | FDE with the limit | H error (m) |",
        "|---|---|---|---|---|---|---|",
    ]
    for s in sorted(old):
        if not args.start <= s <= args.end or s not in new:
            continue
        a, b = old[s], new[s]
        fix = f"{'fix' if a['fix'] else 'RAIM failed'} / {'yes' if a['doppler'] else 'none'}"
        chi = f"{a['chi2']:.0f}" if a["chi2"] is not None else "-"
        rows.append(f"| {s:.0f} | {fix} | {a['fde']} | {chi} | {a['h']:.2f} | {b['fde']} | {b['h']:.2f} |")
    command = ".venv/bin/python bench/far_snapshot_trace.py " + " ".join(sys.argv[1:])
    publish(
        args.out,
        args.block,
        command.strip(),
        f"`coplane simulate --scenario {args.scenario} --seed {args.seed}` (4 vehicles, 200 s), `non-cp` on "
        f"{args.vehicle} alone, with the recording's base; s from the vehicle's first epoch; the limit "
        f"is fde_snapshot_max_chi2 = {args.limit:g}"
        + (", with fde_snapshot_dead_reckon." if args.dead_reckon else "."),
        rows,
    )


if __name__ == "__main__":
    main()
