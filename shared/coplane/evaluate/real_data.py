"""Real-data regression (issue 12, item 5): coplane's estimators beside RTKLIB on recorded receivers.

The real sets are one receiver each, so only single-vehicle methods mean anything here. Static
receivers are processed kinematically: the estimators are not told the antenna stands still, so a
height that runs away while satellites are few shows up as it would in a car.

Two views per method, because they answer different questions:

* all epochs: availability (share of truth epochs with a solution) and the errors where solved;
* common epochs: the truth epochs that RTKLIB *and* the method solve. RTKLIB drops the hard epochs
  (its chi-square/RAIM checks fail there), so a method that solves every epoch would look worse on
  its own set; on the common set both face the same sky.

A moving receiver without truth (`hk_klt_20210610_f9p_rover_hksc_base`) only gets divergence
indicators: the largest step between adjacent epochs, the largest excursion of the height from
the trajectory's median height, and the median horizontal distance to RTKLIB's solution.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field

import numpy as np

from coplane.errors import CoplaneError
from coplane.evaluate.metrics import (
    Consistency,
    PooledStats,
    accuracy,
    covariance_checks,
    enu_errors,
    pooled_stats,
)
from coplane.evaluate.rtklib_row import RTKLIB_METHOD, process_recording, rtklib_unavailable
from coplane.evaluate.runner import lockstep_schedule, run_method
from coplane.geo import ecef_to_geodetic
from coplane.gtime import GpsTime
from coplane.methods import MethodSpec, get_method
from coplane.recording.reader import Recording
from coplane.typing import Vec

DEFAULT_METHODS = ("non-cp", "non-cp-ekf")


@dataclass
class Solutions:
    """Every method's positions for one receiver of a recording, RTKLIB's under "rtklib"."""

    recording: str
    vehicle: str
    dgnss: bool
    n_epochs: int  # nominal epochs of the receiver's schedule
    interval_s: float
    positions: dict[str, dict[GpsTime, Vec]] = field(default_factory=dict)
    covariances: dict[str, dict[GpsTime, Vec]] = field(default_factory=dict)  # ECEF 3x3, as reported
    wall_time_s: dict[str, float] = field(default_factory=dict)
    failures: dict[str, str] = field(default_factory=dict)  # method -> why it gave nothing
    rtklib_note: str = ""


def solve_receiver(
    rec: Recording,
    methods: Iterable[str] = DEFAULT_METHODS,
    *,
    vehicle: str | None = None,
    dgnss: bool | None = None,
    jobs: int | None = 1,
    keep_going: bool = False,
    resolve: Callable[[str], MethodSpec] = get_method,
    rtklib: bool = True,
) -> Solutions:
    """Run `methods` and RTKLIB on one receiver of `rec` in the same mode (DGNSS when None and the
    recording has a base, as `coplane eval`).

    With `keep_going` a method that raises is recorded in `failures` (the benchmark reports it and
    goes on); otherwise the error propagates, which is what tests want. `resolve`: how a method name
    becomes a spec (bench/tune_real_data.py passes variants of the registry's); `rtklib=False`: no
    RTKLIB run (its row is then absent, not failed).
    """
    vid = vehicle or rec.manifest.vehicles[0].id
    use_dgnss = rec.manifest.base is not None if dgnss is None else bool(dgnss)
    out = Solutions(
        recording=rec.manifest.name,
        vehicle=vid,
        dgnss=use_dgnss,
        n_epochs=len(lockstep_schedule(rec, [vid])),
        interval_s=rec.manifest.interval_s,
    )
    for name in methods:
        t0 = time.perf_counter()
        try:
            run = run_method(rec, resolve(name), dgnss=use_dgnss, vehicles=[vid], jobs=jobs)
        except (CoplaneError, ValueError, RuntimeError) as exc:  # pydantic's ValidationError is a ValueError
            if not keep_going:
                raise
            out.failures[name] = f"{type(exc).__name__}: {_first_line(exc)}"
            continue
        out.wall_time_s[name] = time.perf_counter() - t0
        out.positions[name] = dict(run.positions.get(vid, {}))
        out.covariances[name] = dict(run.covariances.get(vid, {}))
    if not rtklib:
        return out
    reason = rtklib_unavailable()
    if reason is not None:
        out.failures[RTKLIB_METHOD] = reason
        return out
    t0 = time.perf_counter()
    try:
        res = process_recording(rec, use_dgnss, vehicles=[vid])
    except (OSError, ValueError, RuntimeError) as exc:
        if not keep_going:
            raise
        out.failures[RTKLIB_METHOD] = f"{type(exc).__name__}: {_first_line(exc)}"
        return out
    out.wall_time_s[RTKLIB_METHOD] = time.perf_counter() - t0
    out.positions[RTKLIB_METHOD] = dict(res.run.positions.get(vid, {}))
    out.covariances[RTKLIB_METHOD] = dict(res.run.covariances.get(vid, {}))
    out.rtklib_note = res.note
    if vid in res.failures:
        out.failures[RTKLIB_METHOD] = res.failures[vid]
    return out


def _first_line(exc: BaseException) -> str:
    lines = [s.strip() for s in str(exc).splitlines() if s.strip()]
    return " / ".join(lines[:3])


# --- static receiver with truth --------------------------------------------------------------


@dataclass(frozen=True)
class ErrorSummary:
    """Errors on a set of epochs (NaN when empty): the median shows the typical epoch, the RMSE and
    the maximum the tail."""

    n: int
    h_median_m: float
    h_rmse_m: float
    v_rmse_m: float
    v_max_m: float  # largest |vertical error|

    @classmethod
    def of(cls, p: PooledStats) -> ErrorSummary:
        return cls(p.n, p.h_p50_m, p.h_rmse_m, p.v_rmse_m, p.v_max_m)


@dataclass(frozen=True)
class StaticRow:
    method: str
    n_truth: int
    availability: float  # share of truth epochs with a solution
    all: ErrorSummary  # every solved truth epoch
    common: ErrorSummary  # truth epochs that RTKLIB and this method both solve
    wall_time_s: float
    # the reported covariances against the errors on every solved epoch (n 0: none reported). On
    # a real receiver this is the check the simulator cannot make: its errors come from the same
    # models as the weights.
    consistency: Consistency


def _subset(positions: Mapping[GpsTime, Vec], keep: Iterable[GpsTime]) -> dict[GpsTime, Vec]:
    return {t: positions[t] for t in keep if t in positions}


def static_accuracy(sol: Solutions, truth: Mapping[GpsTime, Vec]) -> dict[str, StaticRow]:
    """Per method (RTKLIB included): availability, errors on all its epochs and on the common ones.

    Without RTKLIB's solution (pyrtklib missing, RTKLIB failed) the common statistics are NaN.
    """
    ref = sol.positions.get(RTKLIB_METHOD)
    rows: dict[str, StaticRow] = {}
    for name, pos in sol.positions.items():
        st = accuracy(pos, truth)
        times, e_all = enu_errors(pos, truth)
        common = _subset(pos, ref) if ref is not None else {}
        _, e_common = enu_errors(common, truth)
        rows[name] = StaticRow(
            method=name,
            n_truth=st.n_truth,
            availability=st.availability,
            all=ErrorSummary.of(pooled_stats(e_all)),
            common=ErrorSummary.of(pooled_stats(e_common)),
            wall_time_s=sol.wall_time_s.get(name, math.nan),
            consistency=Consistency.of(covariance_checks(times, e_all, sol.covariances.get(name, {}), truth)),
        )
    return rows


def truth_of(rec: Recording, vehicle: str) -> dict[GpsTime, Vec]:
    """The receiver's truth as arrays keyed by nominal epoch ({} when it has none)."""
    return {t: np.asarray(p, dtype=float) for t, p in rec.truth_at(vehicle).items()}


# --- moving receiver without truth -----------------------------------------------------------


@dataclass(frozen=True)
class TrajectoryRow:
    """Divergence indicators of one method's trajectory (no truth needed)."""

    method: str
    n_epochs: int
    availability: float  # share of the receiver's nominal epochs with a solution
    max_step_m: float  # largest 3-D distance between solutions at adjacent nominal epochs
    max_height_excursion_m: float  # largest |height - median height| over the trajectory
    n_common: int  # epochs RTKLIB solves too
    h_median_to_rtklib_m: float  # median horizontal distance to RTKLIB's position there
    wall_time_s: float


def trajectory_checks(sol: Solutions) -> dict[str, TrajectoryRow]:
    """Per method (RTKLIB included): availability, largest step, height excursion, RTKLIB distance.

    A car at up to ~30 m/s cannot step much more than that in one 1 s epoch, and in a small
    district its height stays within a few tens of metres of its median: larger values mean the
    estimator ran away. The distance to RTKLIB is agreement, not accuracy.
    """
    ref = sol.positions.get(RTKLIB_METHOD)
    rows: dict[str, TrajectoryRow] = {}
    for name, pos in sol.positions.items():
        times = sorted(pos)
        xyz = np.array([pos[t] for t in times], dtype=float).reshape(-1, 3)
        steps = [
            float(np.linalg.norm(xyz[k + 1] - xyz[k]))
            for k in range(len(times) - 1)
            if abs((times[k + 1] - times[k]) - sol.interval_s) < 0.1 * sol.interval_s
        ]
        heights = ecef_to_geodetic(xyz)[:, 2] if len(xyz) else np.zeros(0)
        excursion = float(np.max(np.abs(heights - np.median(heights)))) if len(heights) else math.nan
        if ref is not None and name != RTKLIB_METHOD:
            _, e = enu_errors(pos, ref)  # ENU at RTKLIB's point: agreement, not error
            agree = pooled_stats(e)
            n_common, h_med = agree.n, agree.h_p50_m
        else:
            n_common, h_med = len(pos), math.nan
        rows[name] = TrajectoryRow(
            method=name,
            n_epochs=sol.n_epochs,
            availability=len(pos) / sol.n_epochs if sol.n_epochs else 0.0,
            max_step_m=max(steps) if steps else math.nan,
            max_height_excursion_m=excursion,
            n_common=n_common,
            h_median_to_rtklib_m=h_med,
            wall_time_s=sol.wall_time_s.get(name, math.nan),
        )
    return rows


# --- markdown ---------------------------------------------------------------------------------


def _f(x: float, digits: int = 2) -> str:
    return "-" if not math.isfinite(x) else f"{x:.{digits}f}"


def static_table(rows: Mapping[str, StaticRow]) -> str:
    """Markdown table of `static_accuracy` rows."""
    head = (
        "| Method | Avail (%) | H median (m) | H RMSE (m) | V RMSE (m) | max abs V (m) "
        "| common ep. | H median, common (m) | V RMSE, common (m) | H / V inside 95 % | mean NEES | run (s) |\n"
        "|---|---|---|---|---|---|---|---|---|---|---|---|\n"
    )
    body = "".join(
        f"| {r.method} | {100 * r.availability:.1f} | {_f(r.all.h_median_m)} | {_f(r.all.h_rmse_m)} "
        f"| {_f(r.all.v_rmse_m)} | {_f(r.all.v_max_m)} | {r.common.n} | {_f(r.common.h_median_m)} "
        f"| {_f(r.common.v_rmse_m)} | {_f(r.consistency.h_in95)} / {_f(r.consistency.v_in95)} "
        f"| {_f(r.consistency.nees, 1)} | {_f(r.wall_time_s, 1)} |\n"
        for r in rows.values()
    )
    return head + body


def trajectory_table(rows: Mapping[str, TrajectoryRow]) -> str:
    """Markdown table of `trajectory_checks` rows."""
    head = (
        "| Method | Avail (%) | max step (m) | max abs(h - median h) (m) | common ep. "
        "| H median to RTKLIB (m) | run (s) |\n"
        "|---|---|---|---|---|---|---|\n"
    )
    body = "".join(
        f"| {r.method} | {100 * r.availability:.1f} | {_f(r.max_step_m)} | {_f(r.max_height_excursion_m)} "
        f"| {r.n_common} | {_f(r.h_median_to_rtklib_m)} | {_f(r.wall_time_s, 1)} |\n"
        for r in rows.values()
    )
    return head + body


def notes(sol: Solutions) -> str:
    """The RTKLIB mode line and every failure, as markdown lines (empty when there is nothing)."""
    lines = [f"RTKLIB: {sol.rtklib_note.removeprefix('RTKLIB ')}"] if sol.rtklib_note else []
    by_reason: dict[str, list[str]] = {}
    for m, why in sol.failures.items():
        by_reason.setdefault(why, []).append(m)
    lines += [f"**Failed ({', '.join(ms)}):** {why}" for why, ms in by_reason.items()]
    return "\n\n".join(lines)
