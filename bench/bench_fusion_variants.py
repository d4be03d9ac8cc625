"""The estimator's cost and accuracy on cities, per iSAM2 variant (issue 16: the 1.0 ms target).

    .venv/bin/python bench/bench_fusion_variants.py [--vehicles 256] [--duration 20] [--seeds 11,12]
        [--training 11] [--variants isam2-full-check,isam2-extra-1,no-range-warmup] [--repeats 3]
        [--out docs/performance-scale.md] [--block bench_fusion_variants]

For each city seed (`coplane simulate --scenario city`) the pc estimator's epoch inputs are recorded
once (an in-process replay, as `bench_window_clusters.py` does); then the estimator alone runs over
them with its defaults and with each variant of `bench/tune_fgo.py` (one change to the defaults),
`--repeats` times in turn, so the variants share the host's drift. Cost: the median CPU per
vehicle-epoch over the repeats and its ratio to the default's median of the same run; accuracy:
horizontal and vertical RMSE against the simulator's truth (the same in every repeat: the
estimator is deterministic); and how many smoothers were rebuilt from the window (a cluster merged,
split or took a vehicle with earlier states) with their share of the CPU. Cities are the scale the
variants are for; `tune_fgo.py` judges
them on the 4-vehicle training scenarios.
"""

from __future__ import annotations

import argparse
import dataclasses
import platform
import statistics
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))
MARK = "bench_fusion_variants"


def compare(rec_dir: Path, variants: list[str], repeats: int) -> dict[str, dict[str, float]]:
    """Per variant ("default" first): median CPU ms per vehicle-epoch, H and V RMSE, the smoothers
    rebuilt from the window and their share of the CPU (of the median run)."""
    import bench_window_clusters as recorder
    from fgo_variants import VARIANTS

    config, inputs = recorder.record_inputs(rec_dir)  # pc's estimator config, defaults
    configs = {"default": config} | {v: dataclasses.replace(config, **VARIANTS[v]) for v in variants}  # type: ignore[arg-type]
    runs: dict[str, list[dict[str, float]]] = {v: [] for v in configs}
    for _ in range(repeats):
        for name, cfg in configs.items():
            runs[name].append(recorder.replay(rec_dir, cfg, inputs, cfg.window_cluster_max))
    out = {}
    for name, rs in runs.items():
        mid = sorted(rs, key=lambda r: r["ms"])[len(rs) // 2]
        out[name] = {
            "ms": statistics.median(r["ms"] for r in rs),
            "h": rs[0]["h"],
            "v": rs[0]["v"],
            "rebuilds": rs[0]["rebuilds"],
            "rebuild_share": mid["rebuild_share"],
        }
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--vehicles", type=int, default=256)
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--seeds", default="11,12")
    ap.add_argument("--training", default="11", help="seeds the defaults were chosen on")
    ap.add_argument("--variants", default="isam2-full-check,isam2-extra-1,no-range-warmup")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--block", default=MARK, help="the docs block to write (a page may hold several)")
    args = ap.parse_args()
    import bench_window_clusters as recorder
    from docblock import on_service_allocator, write_block

    malloc = on_service_allocator()  # the services' allocator: their CPU figures

    seeds = [int(s) for s in args.seeds.split(",")]
    training = {int(s) for s in args.training.split(",")}
    variants = [v for v in args.variants.split(",") if v]
    rows = [
        f"| city seed | role | variant | fusion CPU ms / vehicle-epoch (median of {args.repeats}) | vs default "
        "| H RMSE (m) | V RMSE (m) | smoothers rebuilt | their share of the CPU |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    with tempfile.TemporaryDirectory(prefix="coplane-variants-") as tmp:
        for seed in seeds:
            rec_dir = Path(tmp) / f"city-{seed}"
            recorder.simulate_city(rec_dir, args.vehicles, args.duration, seed)
            res = compare(rec_dir, variants, args.repeats)
            role = "training" if seed in training else "report"
            base = res["default"]["ms"]
            for name, r in res.items():
                rows.append(
                    f"| {seed} | {role} | {name} | {r['ms']:.2f} | {r['ms'] / base:.2f} | {r['h']:.3f} | {r['v']:.3f} "
                    f"| {r['rebuilds']:.0f} | {100 * r['rebuild_share']:.0f} % |"
                )
            print("\n".join(rows[-len(res) :]), flush=True)
    head = (
        f"machine: {platform.machine()}, Python {platform.python_version()}, malloc {malloc}; cities of {args.vehicles} vehicles x "
        f"{args.duration:.0f} s, method pc, the estimator alone on recorded inputs, each variant one change to "
        "the defaults (`bench/tune_fgo.py`)"
    )
    table = head + "\n\n" + "\n".join(rows)
    print(table)
    if args.out is not None:
        cmd = (
            f"python bench/bench_fusion_variants.py --vehicles {args.vehicles} --duration {args.duration:.0f} "
            f"--seeds {args.seeds} --training {args.training} --variants {args.variants} --repeats {args.repeats} "
            f"--out {args.out}" + (f" --block {args.block}" if args.block != MARK else "")
        )
        write_block(args.out, args.block, cmd, table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
