"""How often the cooperative exclusion (`FgoConfig.coop_fde_k`, docs/fgo.md) fires: the
pseudoranges it excludes against those the vehicles' FDE tested, on one training seed of each
scenario. Prints; nothing here chooses a default.

    .venv/bin/python bench/count_coop_exclusions.py [--k 2.5]
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import tempfile
from pathlib import Path

import numpy as np

import coplane.fgo.engine as engine
from coplane.evaluate.benchmark import make_recordings
from coplane.evaluate.runner import run_method
from coplane.fgo import cooperative
from coplane.fgo.prepare import Prepared
from coplane.fgo.state import StepStats
from coplane.methods import get_method

SEEDS = (("dense-urban", 201), ("urban-loop", 101))  # training seeds (bench/tune_fgo.py)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--k", type=float, default=2.5)
    args = ap.parse_args()
    counts: collections.Counter[str] = collections.Counter()

    def counted(preps: dict[str, Prepared], k: float, radius_m: float, stats: StepStats) -> None:
        """The engine's call, with the tested and excluded pseudoranges counted."""
        counts["tested"] += sum(
            int(np.isfinite(p.fde_w).sum()) for p in preps.values() if p.fde_w is not None
        )
        before = stats.rejected.get("coop_pseudorange", 0)
        cooperative.cooperative_exclusion(preps, k, radius_m, stats)
        counts["excluded"] += stats.rejected.get("coop_pseudorange", 0) - before

    engine.cooperative_exclusion = counted  # type: ignore[assignment]  # a counter around the real one
    pc = get_method("pc")
    assert pc.fgo is not None
    spec = dataclasses.replace(pc, fgo=dataclasses.replace(pc.fgo, coop_fde_k=args.k))
    print(
        f"| scenario, seed (200 s, 4 vehicles) | pseudoranges tested | excluded by coop k={args.k} | share |"
    )
    print("|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for scen, seed in SEEDS:
            counts.clear()
            rec = make_recordings(scen, [seed], Path(tmp), 4, 200.0)[0]
            run_method(rec, spec)
            share = counts["excluded"] / max(counts["tested"], 1)
            print(f"| {scen} {seed} | {counts['tested']} | {counts['excluded']} | {share:.3f} |")


if __name__ == "__main__":
    main()
