"""The held-out benchmark: methods pooled over several fresh simulator seeds per scenario.

Defaults are tuned on `TRAINING` (bench/tune_fgo.py), a choice training cannot settle is checked
on `VALIDATION`, and they are reported on `HELD_OUT`, never the other way round; docs/results.md is regenerated from here by bench/make_results.py, and the ordering
tests (tests/evaluate/test_benchmark_ordering.py) run a held-out seed too. Errors are pooled over
every vehicle of every seed of a scenario, overall and per environment of the truth, so the deep
canyons and underpasses where methods differ are visible next to the fleet RMSE.
"""

from __future__ import annotations

import importlib.metadata
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_info

from coplane.evaluate.front_ends import FrontEndMemo
from coplane.evaluate.metrics import (
    Consistency,
    EpochCheck,
    PooledStats,
    accuracy_by_environment,
    covariance_checks,
    enu_errors,
)
from coplane.evaluate.runner import run_method
from coplane.gnss.epoch_solver import EpochSolverOptions
from coplane.methods import MethodSpec
from coplane.plane.config import PlaneConfig
from coplane.recording.reader import Recording, open_recording
from coplane.sim.generate import simulate

# Seeds the defaults were chosen on (bench/tune_fgo.py): never reported.
TRAINING: dict[str, tuple[int, ...]] = {
    "urban-loop": tuple(range(101, 111)),
    "dense-urban": tuple(range(201, 207)),
}
# Seeds that checked choices the training seeds won but could not settle: the road-height links
# were judged on them three times (docs/fgo.md). They were the reported seeds until 2026-11-27;
# once a seed has decided a default, it is no longer fresh, so they are never reported again.
VALIDATION: dict[str, tuple[int, ...]] = {
    "urban-loop": (301, 302, 303, 304, 305),
    "dense-urban": (401, 402, 403, 404, 405),
}
# Seeds that vetoed a candidate default in a regeneration of docs/results.md, so that they are no
# longer fresh and are neither reported nor tuned on again (docs/fgo.md): 701-705 / 801-805,
# reported 2026-11-27 to 2026-11-29, vetoed the innovation gate; 901-905 / 1001-1005, reported
# 2026-11-29 to 2026-11-30, vetoed `fde_snapshot_max_chi2` alone (a 50 m tail on urban-loop 903).
RETIRED: dict[str, tuple[int, ...]] = {
    "urban-loop": (701, 702, 703, 704, 705, 901, 902, 903, 904, 905),
    "dense-urban": (801, 802, 803, 804, 805, 1001, 1002, 1003, 1004, 1005),
}
# Seeds of the simulator's other scenarios, looked at on 2026-11-30 for what the two above do not
# have (a city's streets, an open sky): they found a default (`FgoConfig.fde_snapshot_max_chi2`,
# docs/fgo.md) and so are no longer fresh; never reported as held-out results.
EXPLORATION: dict[str, tuple[int, ...]] = {
    "city": (1201, 1202, 1203, 1204, 1205),
    "open-sky": (1101, 1102),
}
# Seeds reported in docs/results.md and used by the ordering tests: never used for tuning, never
# to decide anything (chosen 2026-11-30 before any run on them).
HELD_OUT: dict[str, tuple[int, ...]] = {
    "urban-loop": (1501, 1502, 1503, 1504, 1505),
    "dense-urban": (1601, 1602, 1603, 1604, 1605),
}
# Seeds of the simulator's other scenarios reported beside them (docs/results.md, "other
# scenarios"): never tuned on (chosen 2026-11-30 before any run on them, after EXPLORATION).
HELD_OUT_OTHER: dict[str, tuple[int, ...]] = {
    "city": (1301, 1302, 1303, 1304, 1305),
    "open-sky": (1401, 1402, 1403),
}
BASELINES = ("non-cp-ekf", "dd-cp", "gamp-cp")
# Length of each held-out recording (4 vehicles): docs/results.md and the ordering tests alike.
HELD_OUT_DURATION_S = 200.0


@dataclass(frozen=True)
class Check:
    """One acceptance ratio of the benchmark: `value` must be <= `limit`."""

    name: str
    value: float
    limit: float

    @property
    def ok(self) -> bool:
        return bool(self.value <= self.limit)


NUMERIC_PACKAGES = ("gtsam", "numpy", "scipy")


def numeric_versions() -> str:
    """The numeric libraries' versions, for a benchmark's header. A fresh install moves pooled
    figures in the second decimal: the same commit (06bdd65) gave a training dense-urban `pc`
    H p99 of 9.81 m in one session and 10.09 m after a new `scripts/setup.sh` in the next
    (library versions or the BLAS kernel; which one was not isolated), so a table names them, and
    every BLAS loaded (numpy's and scipy's each bring one) with the kernels it picked for this CPU
    (OPENBLAS_CORETYPE sets them)."""
    out = [f"{p} {importlib.metadata.version(p)}" for p in NUMERIC_PACKAGES]
    for lib in threadpool_info():
        if lib.get("user_api") == "blas":
            kernel = lib.get("architecture")
            out.append(
                f"{lib.get('internal_api')} {lib.get('version')}" + (f" ({kernel} kernels)" if kernel else "")
            )
    return ", ".join(out)


def make_recordings(
    scenario: str,
    seeds: Sequence[int],
    out_dir: Path,
    vehicles: int = 4,
    duration_s: float = 300.0,
    doppler: bool = True,
) -> list[Recording]:
    """Simulate (or reuse, if already written) one recording per seed; `doppler` False: receivers
    that log no Doppler (`coplane.sim.write.write_recording`), the same drives otherwise."""
    recs = []
    for seed in seeds:
        path = out_dir / f"{scenario}-{seed}{'' if doppler else '-no-doppler'}"
        if not (path / "fleet.toml").exists():
            simulate(scenario, path, vehicles, duration_s, seed, doppler=doppler)
        recs.append(open_recording(path))
    return recs


@dataclass(frozen=True)
class TailEpoch:
    """One epoch whose horizontal error exceeds the tail threshold: where and when it happened."""

    recording: str
    vehicle: str
    seconds: float  # since the vehicle's first solved truth epoch
    environment: str
    h_error_m: float


def pooled_by_environment(
    recs: Sequence[Recording],
    method: MethodSpec | str,
    jobs: int | None = None,
    on_run: Callable[[str, float], None] | None = None,
    tail: list[TailEpoch] | None = None,
    tail_m: float = 20.0,
    dgnss: bool | None = None,
    front_end: EpochSolverOptions | None = None,
    plane_config: PlaneConfig | None = None,
    front_ends: FrontEndMemo | None = None,
) -> tuple[dict[str, PooledStats], Consistency]:
    """One method's errors pooled over every vehicle of every recording, overall and per
    environment, and the consistency of its reported covariances (NaN share when it has none).
    Epochs with a horizontal error above `tail_m` are appended to `tail` when it is given.
    `dgnss`, `front_end`, `plane_config`: as `run_method` (None: with the recording's base when it
    has one; the default GNSS front end; the default plane step). `front_ends`: as `run_method` (one
    memo for every method's call computes the GNSS front ends once)."""
    sol: dict[str, dict] = {}
    truth: dict[str, dict] = {}
    env: dict[str, dict] = {}
    checks: list[EpochCheck] = []
    for k, rec in enumerate(recs):
        run = run_method(
            rec,
            method,
            jobs=jobs,
            dgnss=dgnss,
            front_end=front_end,
            plane_config=plane_config,
            front_ends=front_ends,
        )
        if on_run is not None:
            on_run(run.method, run.wall_time_s)
        for v in rec.manifest.vehicles:
            key = f"{k}:{v.id}"  # vehicles of different recordings stay apart
            sol[key] = run.positions.get(v.id, {})
            truth[key] = {t: np.asarray(p) for t, p in rec.truth_at(v.id).items()}
            env[key] = rec.environment_at(v.id)
            times, errs = enu_errors(sol[key], truth[key])
            if tail is not None:
                for t, e in zip(times, errs, strict=True):
                    h = float(np.hypot(e[0], e[1]))
                    if h > tail_m:
                        tail.append(
                            TailEpoch(rec.manifest.root.name, v.id, t - times[0], env[key].get(t, ""), h)
                        )
            checks += covariance_checks(times, errs, run.covariances.get(v.id, {}), truth[key])
    return accuracy_by_environment(sol, truth, env), Consistency.of(checks)


def consistency_table(cons: dict[str, Consistency]) -> str:
    """Markdown: per method, the shares of epochs inside the reported 95 % regions (0.95 if honest)
    and the mean NEES (3 if honest)."""
    lines = [
        "| Method | epochs | H inside 95 % ellipse | V inside 95 % interval | mean NEES (3 if honest) |",
        "|---|---|---|---|---|",
    ]
    for m, c in cons.items():
        if c.n:
            lines.append(f"| {m} | {c.n} | {c.h_in95:.2f} | {c.v_in95:.2f} | {c.nees:.2f} |")
    return "\n".join(lines)


def acceptance(stats: dict[str, dict[str, PooledStats]]) -> list[Check]:
    """The issue's orderings as ratios (value <= limit), from whichever methods were run."""
    a = {m: s["all"] for m, s in stats.items()}
    out: list[Check] = []
    base = [m for m in BASELINES if m in a]
    if "pc" in a and base:
        best_h = min(a[m].h_rmse_m for m in base)
        best_v = min(a[m].v_rmse_m for m in base)
        out.append(Check("pc H-RMSE / best baseline H-RMSE", a["pc"].h_rmse_m / best_h, 0.85))
        out.append(Check("pc V-RMSE / best baseline V-RMSE", a["pc"].v_rmse_m / best_v, 0.6))
    if "pc" in a and "mci" in a:
        out.append(Check("pc H-RMSE / mci H-RMSE", a["pc"].h_rmse_m / a["mci"].h_rmse_m, 1.0))
        out.append(Check("pc V-RMSE / mci V-RMSE", a["pc"].v_rmse_m / a["mci"].v_rmse_m, 0.6))
    if "non-cp" in a and "non-cp-ekf" in a:
        out.append(
            Check("non-cp H-RMSE / non-cp-ekf H-RMSE", a["non-cp"].h_rmse_m / a["non-cp-ekf"].h_rmse_m, 1.0)
        )
        out.append(
            Check("non-cp V-RMSE / non-cp-ekf V-RMSE", a["non-cp"].v_rmse_m / a["non-cp-ekf"].v_rmse_m, 1.0)
        )
    return out


def checks_table(checks: Sequence[Check]) -> str:
    """Markdown: each ratio, its limit and whether it holds."""
    lines = ["| ratio | measured | required | holds |", "|---|---|---|---|"]
    lines += [
        f"| {c.name} | {c.value:.2f} | <= {c.limit:.2f} | {'yes' if c.ok else '**no**'} |" for c in checks
    ]
    return "\n".join(lines)


def tail_summary(tail: Sequence[TailEpoch], method: str, tail_m: float = 20.0) -> str:
    """One line per vehicle with epochs above the threshold: when (s from its start) and where."""
    if not tail:
        return f"`{method}`: no epoch with a horizontal error above {tail_m:.0f} m."
    by: dict[tuple[str, str], list[TailEpoch]] = {}
    for e in tail:
        by.setdefault((e.recording, e.vehicle), []).append(e)
    parts = []
    for (rec, vid), es in sorted(by.items()):
        worst = max(es, key=lambda e: e.h_error_m)
        envs = ", ".join(sorted({e.environment for e in es if e.environment}))
        parts.append(
            f"{rec} {vid}: {len(es)} epochs between {min(e.seconds for e in es):.0f} and "
            f"{max(e.seconds for e in es):.0f} s after its first solution ({envs}), worst {worst.h_error_m:.1f} m"
        )
    return f"`{method}` epochs with a horizontal error above {tail_m:.0f} m: " + "; ".join(parts) + "."
