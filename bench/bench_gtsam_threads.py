"""Does GTSAM's Python wrapper let two threads optimise at once? (issue 16: parallel clusters)

    .venv/bin/python bench/bench_gtsam_threads.py

Two independent graphs (3000 Point3 states in a chain, the size of a large cluster's window)
optimised 5 times each with Levenberg-Marquardt, first one after the other, then in two threads.
If the wrapper released the GIL during `optimize`, the threaded run would take about half the
time on two cores; the ratio printed is threaded / serial wall time, median of `--repeat` runs.
"""

from __future__ import annotations

import argparse
import statistics
import threading
import time

import gtsam


def make_graph(n: int) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
    g = gtsam.NonlinearFactorGraph()
    v = gtsam.Values()
    noise = gtsam.noiseModel.Isotropic.Sigma(3, 0.1)
    g.add(gtsam.PriorFactorPoint3(0, gtsam.Point3(0, 0, 0), noise))
    for i in range(n):
        v.insert(i, gtsam.Point3(i, 0.1, 0))
        if i:
            g.add(gtsam.BetweenFactorPoint3(i - 1, i, gtsam.Point3(1, 0, 0), noise))
    return g, v


def optimise(gv: tuple[gtsam.NonlinearFactorGraph, gtsam.Values], times: int) -> None:
    for _ in range(times):
        gtsam.LevenbergMarquardtOptimizer(gv[0], gv[1]).optimize()


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--states", type=int, default=3000)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    a, b = make_graph(args.states), make_graph(args.states)
    serial, threaded = [], []
    for _ in range(args.repeat):
        t = time.perf_counter()
        optimise(a, 5)
        optimise(b, 5)
        serial.append(time.perf_counter() - t)
        t = time.perf_counter()
        ths = [threading.Thread(target=optimise, args=(x, 5)) for x in (a, b)]
        for th in ths:
            th.start()
        for th in ths:
            th.join()
        threaded.append(time.perf_counter() - t)
    s, p = statistics.median(serial), statistics.median(threaded)
    print(f"gtsam {gtsam.__version__ if hasattr(gtsam, '__version__') else '?'}: serial {s:.3f} s, "
          f"two threads {p:.3f} s, threaded / serial = {p / s:.2f} (0.5 would be two cores used)")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
