"""Node messages with their satellites as columns against an object per satellite (issue 16).

    .venv/bin/python bench/bench_node_decode.py [--vehicles 256] [--duration 20] [--seed 11]
        [--repeats 5] [--out docs/performance-scale.md]

A fusion server decodes every node message, checks its SPP fix against its own pseudoranges
(admission, `plausibility.spp_problem`) and gathers the used satellites into the estimator's
columns (`steps.wire.pseudorange_columns`). Until 2026-12-03 the wire carried one JSON object per
satellite (`coplane.node/1`), which pydantic validated into a `SatelliteReport` each; since then
one list per field (`coplane.node/2`, `messages.SatelliteColumns`). This measures both layouts of
the same messages: a simulated city (`coplane simulate --scenario city`) is replayed in process
with method pc, keeping every node message as the bus carries it and the CPU of the estimator's
step (`FusionEstimator.step`, the larger part of a server); then, per message, the best of
`--repeats` passes over all of them:

- decoding: `NodeMessage` as it is, and `RowNode` below, the same model with the satellites as a
  list of `SatelliteReport` (the /1 layout, every bound and check the same);
- gathering the used satellites into arrays, which the self-check and the columns each do: from
  the columns as `plausibility` and `steps.wire` do now, and from the objects as they did (the
  arithmetic after the gather is the same in either layout and is not timed);
- and, for the whole picture, the self-check and the columns as they are now.

Everything is CPU time of one process (`time.process_time`), in one run. The server as a whole,
before and after, is `bench/bench_scale_ab.py` (docs/performance-scale.md, "Node messages as
columns").
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))
MARK = "bench_node_decode"


def row_model() -> type[Any]:
    """`NodeMessage` with its satellites as a list of `SatelliteReport` (the /1 layout): each row
    checks its own bounds and orbit radius, the message that no satellite repeats."""
    from pydantic import Field, create_model, model_validator

    from coplane.messages import MAX_SATELLITES, NodeMessage, SatelliteReport

    def unique(self: Any) -> Any:
        sats = [s.sat for s in self.satellites]
        if len(set(sats)) != len(sats):
            raise ValueError("duplicate satellite in one node message")
        peers = [r.to for r in self.ranges]
        if len(set(peers)) != len(peers) or self.vehicle_id in peers:
            raise ValueError("ranges must name each peer once and not the vehicle itself")
        return self

    fields = {n: (f.annotation, f) for n, f in NodeMessage.model_fields.items() if n != "satellites"}
    return create_model(  # type: ignore[no-any-return, call-overload]
        "RowNode",
        __config__=NodeMessage.model_config,
        __validators__={"unique": model_validator(mode="after")(unique)},
        satellites=(list[SatelliteReport], Field(default_factory=list, max_length=MAX_SATELLITES)),
        **fields,
    )


def to_rows(payload: bytes) -> bytes:
    """A node message's JSON with an object per satellite (what a /1 agent sent)."""
    d = json.loads(payload)
    cols = d["satellites"]
    d["satellites"] = [dict(zip(cols, vals, strict=True)) for vals in zip(*cols.values(), strict=True)]
    return json.dumps(d).encode()


def gather_columns(msg: Any) -> tuple[np.ndarray, np.ndarray]:
    """The used satellites' positions and numbers as arrays, from the columns (as now)."""
    s = msg.satellites
    used = np.array(s.used, dtype=bool)
    pos = np.array(s.sat_pos_ecef_m, dtype=float).reshape(-1, 3)[used]
    num = np.array([s.rho_m, s.sat_clock_s, s.sigma_m, s.elevation_deg, s.iono_m], dtype=float)[:, used]
    return pos, num


def gather_rows(msg: Any) -> tuple[np.ndarray, np.ndarray]:
    """The same arrays from an object per satellite (as the /1 code did)."""
    used = [s for s in msg.satellites if s.used]
    pos = np.array([s.sat_pos_ecef_m for s in used], dtype=float).reshape(len(used), 3)
    num = np.array(
        [(s.rho_m, s.sat_clock_s, s.sigma_m, s.elevation_deg, s.iono_m) for s in used], dtype=float
    )
    return pos, num


def collect(rec_dir: Path) -> tuple[list[bytes], float, int]:
    """Every node message of a pc replay as the bus carries it, the estimator step's CPU seconds
    and the vehicle-epochs it solved."""
    from coplane.bus import encode
    from coplane.evaluate.runner import run_method
    from coplane.fgo.engine import FusionEstimator
    from coplane.recording.reader import open_recording

    payloads: list[bytes] = []
    cpu = [0.0, 0]
    step = FusionEstimator.step

    def timed_step(self: FusionEstimator, epoch: Any) -> Any:
        c0 = time.process_time()
        try:
            return step(self, epoch)
        finally:
            cpu[0] += time.process_time() - c0
            cpu[1] += len(epoch.vehicles)

    def keep(sol: Any, msgs: dict[str, Any]) -> None:
        payloads.extend(encode(m) for m in msgs.values())

    FusionEstimator.step = timed_step  # type: ignore[method-assign]
    try:
        run_method(open_recording(rec_dir), "pc", jobs=1, on_solution=keep)
    finally:
        FusionEstimator.step = step  # type: ignore[method-assign]
    return payloads, float(cpu[0]), int(cpu[1])


def per_item_us(
    jobs: dict[str, tuple[Callable[[Any], object], Sequence[Any]]], repeats: int
) -> dict[str, float]:
    """CPU microseconds per item of each job (a function and its items), the best of `repeats`
    rounds, each round running every job once in turn: the host's speed drifts within minutes,
    so the two layouts are timed side by side, not one after the other."""
    best = dict.fromkeys(jobs, float("inf"))
    for _ in range(repeats):
        for name, (fn, items) in jobs.items():
            c0 = time.process_time()
            for x in items:
                fn(x)
            best[name] = min(best[name], time.process_time() - c0)
    return {name: 1e6 * best[name] / len(jobs[name][1]) for name in jobs}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--vehicles", type=int, default=256)
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    import bench_window_clusters as city
    from docblock import machine, on_service_allocator, publish

    from coplane.fusion_server.plausibility import SPP_RESIDUAL_M, spp_problem
    from coplane.messages import NodeMessage
    from coplane.steps.wire import pseudorange_columns

    malloc = on_service_allocator()
    with tempfile.TemporaryDirectory(prefix="coplane-node-decode-") as tmp:
        rec = Path(tmp) / "city"
        city.simulate_city(rec, args.vehicles, args.duration, args.seed)
        payloads, step_cpu, n = collect(rec)
    row_payloads = [to_rows(p) for p in payloads]
    rows_of = row_model()
    msgs = [NodeMessage.model_validate_json(p) for p in payloads]
    row_msgs = [rows_of.model_validate_json(p) for p in row_payloads]
    r = args.repeats
    step_us = 1e6 * step_cpu / n
    us = per_item_us(
        {
            "decode /1": (lambda p: rows_of.model_validate_json(p), row_payloads),
            "decode /2": (lambda p: NodeMessage.model_validate_json(p), payloads),
            "gather /1": (gather_rows, row_msgs),
            "gather /2": (gather_columns, msgs),
            "SPP self-check": (lambda m: spp_problem(m, SPP_RESIDUAL_M), msgs),
            "estimator columns": (pseudorange_columns, msgs),
        },
        r,
    )
    parts = {
        "decoding": (us["decode /1"], us["decode /2"]),
        "used satellites gathered into arrays (x2: self-check, columns)": (
            2 * us["gather /1"],
            2 * us["gather /2"],
        ),
    }
    rows = [
        "| part | object per satellite (/1) us / message | columns (/2) us / message | /2 - /1, of the estimator's step |",
        "|---|---|---|---|",
    ]
    for part, (a, b) in parts.items():
        rows.append(f"| {part} | {a:.1f} | {b:.1f} | {100 * (b - a) / step_us:+.1f} % |")
    ta, tb = (sum(v[i] for v in parts.values()) for i in (0, 1))
    rows.append(f"| **both** | **{ta:.1f}** | **{tb:.1f}** | **{100 * (tb - ta) / step_us:+.1f} %** |")
    now = {k: us[k] for k in ("SPP self-check", "estimator columns")}
    size = (sum(map(len, row_payloads)) / len(row_payloads), sum(map(len, payloads)) / len(payloads))
    rows += [
        "",
        f"Estimator step (`FusionEstimator.step`, the same replay): {step_us:.0f} us per vehicle-epoch. "
        f"Now, whole: the SPP self-check {now['SPP self-check']:.1f} us, the estimator columns "
        f"{now['estimator columns']:.1f} us per message. "
        f"Message size: {size[0]:.0f} bytes with an object per satellite, {size[1]:.0f} as columns.",
    ]
    head = (
        f"machine: {machine()}, malloc {malloc}; city of {args.vehicles} vehicles x {args.duration:.0f} s "
        f"(seed {args.seed}), method pc: {len(payloads)} node messages "
        f"({np.mean([len(m.satellites) for m in msgs]):.1f} satellites each), best of {r} rounds, each timing every part in turn"
    )
    cmd = (
        f"python bench/bench_node_decode.py --vehicles {args.vehicles} --duration {args.duration:.0f} "
        f"--seed {args.seed} --repeats {r} --out {args.out}"
    )
    publish(args.out, MARK, cmd, head, rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
