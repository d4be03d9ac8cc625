"""Solution files other tools open: RTKLIB .pos (RTKPLOT, rtklib-py, ...) and TUM trajectories (evo)."""

from __future__ import annotations

import math
from collections.abc import Collection, Iterable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from coplane import __version__
from coplane.errors import ConfigError
from coplane.geo import ecef_to_enu, ecef_to_geodetic, enu_rotation
from coplane.gtime import GpsTime
from coplane.messages import FixKind, fix_kind
from coplane.recording.trajectories import Q_DGPS, Q_DR, Q_SINGLE, PosRecord
from coplane.typing import Vec

if TYPE_CHECKING:
    from coplane.evaluate.runner import MethodRun
    from coplane.recording.reader import Recording


SOLUTION_FORMATS = ("tum", "pos")  # `--format`: solution files beside the CSVs, for other tools


def check_formats(formats: Collection[str]) -> None:
    """ConfigError naming any format that is not one of `SOLUTION_FORMATS`."""
    unknown = set(formats) - set(SOLUTION_FORMATS)
    if unknown:
        raise ConfigError(
            f"unknown --format {', '.join(sorted(unknown))} (expected {', '.join(SOLUTION_FORMATS)})"
        )


def _sq(v: float) -> float:
    """RTKLIB's signed square root for covariance terms."""
    return math.copysign(math.sqrt(abs(v)), v)


def pos_text(records: Iterable[PosRecord], inputs: Iterable[str] = (), mode: str = "single") -> str:
    """RTKLIB's llh .pos layout (GPST calendar time) of these records: what RTKPLOT reads."""
    lines = [f"% program   : coplane {__version__}"]
    lines += [f"% inp file  : {p}" for p in inputs]
    lines += [
        f"% pos mode  : {mode}",
        "% (lat/lon/height=WGS84/ellipsoidal,Q=1:fix,2:float,3:sbas,4:dgps,5:single,6:ppp,7:dr,ns=# of satellites)",
        "%  GPST                  latitude(deg) longitude(deg)  height(m)   Q  ns   sdn(m)   sde(m)   sdu(m)"
        "  sdne(m)  sdeu(m)  sdun(m) age(s)  ratio",
    ]
    for r in records:
        lat, lon, h = ecef_to_geodetic(r.ecef)
        rot = enu_rotation(lat, lon)
        q = rot @ np.asarray(r.covariance, dtype=float) @ rot.T
        if not np.all(np.isfinite(q)):
            q = np.zeros((3, 3))
        y, mo, d, hh, mi, s = GpsTime(r.time.week, round(r.time.tow, 3)).to_calendar()
        lines.append(
            f"{y:04d}/{mo:02d}/{d:02d} {hh:02d}:{mi:02d}:{s:06.3f} "
            f"{math.degrees(lat):14.9f} {math.degrees(lon):14.9f} {h:10.4f} {r.quality:3d} {r.n_sats:3d} "
            f"{_sq(q[1, 1]):8.4f} {_sq(q[0, 0]):8.4f} {_sq(q[2, 2]):8.4f} "
            f"{_sq(q[1, 0]):8.4f} {_sq(q[0, 2]):8.4f} {_sq(q[2, 1]):8.4f} {r.age_s:6.2f} {0.0:6.1f}"
        )
    return "\n".join(lines) + "\n"


def write_pos(
    path: Path, records: Iterable[PosRecord], inputs: Iterable[str] = (), mode: str = "single"
) -> int:
    """Write `pos_text` to `path`; returns the number of records."""
    recs = list(records)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(pos_text(recs, inputs, mode))
    return len(recs)


# RTKLIB's Q of each kind of fused solution (7 is RTKLIB's dead reckoning, SOLQ_DR)
POS_QUALITY: dict[FixKind, int] = {"dgnss": Q_DGPS, "single": Q_SINGLE, "dead-reckoned": Q_DR}


def pos_quality(gnss_fix: bool, dgnss_age_s: float | None) -> int:
    """RTKLIB's Q of a fused solution: 4 (DGPS), 5 (single) or 7 (dead reckoning) by
    `messages.fix_kind`."""
    return POS_QUALITY[fix_kind(gnss_fix, dgnss_age_s)]


def fused_pos_record(
    t: GpsTime, ecef: ArrayLike, cov: ArrayLike | None, gnss_fix: bool, dgnss_age_s: float | None, n_kept: int
) -> PosRecord:
    """One fused solution as a .pos row: Q by `pos_quality`, ns the pseudoranges the estimator
    kept, the standard deviations its reported covariance (zeros where it reported none, as RTKLIB
    writes them), age the corrections' age (0 without)."""
    return PosRecord(
        t,
        np.asarray(ecef, dtype=float),
        np.zeros((3, 3)) if cov is None else np.asarray(cov, dtype=float).reshape(3, 3),
        pos_quality(gnss_fix, dgnss_age_s),
        int(n_kept),
        0.0 if dgnss_age_s is None else float(dgnss_age_s),
    )


def method_pos_records(run: MethodRun, vid: str) -> list[PosRecord]:
    """One vehicle's solutions of a run as .pos rows (`fused_pos_record`)."""
    covs = run.covariances.get(vid, {})
    fixes = run.gnss_fix.get(vid, {})
    ages = run.dgnss_age_s.get(vid, {})
    kept = run.pseudoranges_used.get(vid, {})
    return [
        fused_pos_record(t, p, covs.get(t), fixes.get(t, True), ages.get(t), kept.get(t, 0))
        for t, p in sorted(run.positions.get(vid, {}).items(), key=lambda tp: tp[0])
    ]


def write_method_pos(run: MethodRun, out_dir: Path, inputs: Iterable[str] = ()) -> list[Path]:
    """solutions/<method>/<vehicle>.pos for every vehicle of a run: RTKPLOT (or any .pos reader)
    then shows coplane's solutions beside RTKLIB's, with their quality flags and sigmas."""
    paths = []
    for vid in sorted(run.positions):
        path = Path(out_dir) / "solutions" / run.label / f"{vid}.pos"
        write_pos(path, method_pos_records(run, vid), inputs, mode=f"coplane {run.label}")
        paths.append(path)
    return paths


# --------------------------------------------------------------------------------------------
# TUM trajectories: "timestamp x y z qx qy qz qw", what evo reads (`evo_traj tum`, `evo_ape tum`)

TUM_HEADER = "# timestamp x y z qx qy qz qw"


def tum_origin(rec: Recording) -> Vec | None:
    """The ENU origin every TUM file of a recording shares: its base station, else the first truth
    point of its first vehicle with truth, else None (then files are ECEF)."""
    if rec.manifest.base is not None:
        return np.asarray(rec.manifest.base.position_ecef_m, dtype=float)
    for v in rec.manifest.vehicles:
        truth = rec.truth(v.id)
        if truth:
            return np.asarray(truth[0].ecef_m, dtype=float)
    return None


def _tum_lines(points: Iterable[tuple[GpsTime, Vec]], origin_ecef: Vec | None) -> list[str]:
    lines = [
        TUM_HEADER + (" (ENU metres about the origin below)" if origin_ecef is not None else " (ECEF metres)")
    ]
    if origin_ecef is not None:
        lines.append("# origin_ecef_m " + " ".join(f"{c:.4f}" for c in np.asarray(origin_ecef, dtype=float)))
    for t, p in sorted(points, key=lambda tp: tp[0]):
        xyz = np.asarray(p, dtype=float)
        if not np.all(np.isfinite(xyz)):
            continue
        if origin_ecef is not None:
            xyz = ecef_to_enu(xyz, origin_ecef)
        lines.append(f"{t.seconds:.6f} {xyz[0]:.4f} {xyz[1]:.4f} {xyz[2]:.4f} 0 0 0 1")
    return lines


def write_tum_file(path: Path, points: Iterable[tuple[GpsTime, Vec]], origin_ecef: Vec | None = None) -> int:
    """One trajectory as TUM: timestamp = GPS seconds since 1980-01-06 (week * 604800 + tow),
    position in ENU about `origin_ecef` (ECEF when None), identity orientation (GNSS gives none)."""
    lines = _tum_lines(points, origin_ecef)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")
    return sum(1 for x in lines if not x.startswith("#"))


def write_tum(run: MethodRun, out_dir: Path, origin_ecef: Vec | None = None) -> list[Path]:
    """solutions/<method>/<vehicle>.tum for every vehicle of a run.

    Why ENU about one fixed origin (`tum_origin`: the base station or the first truth point) and
    not about each vehicle's first solution: evo compares files point by point, so every method's
    file and the truth (`write_truth_tum`) must share one frame, and a first solution differs
    between methods. ENU keeps evo's xy plots horizontal; without an origin the files are ECEF,
    which evo reads just as well (float64) but plots tilted.
    """
    paths = []
    for vid in sorted(run.positions):
        path = Path(out_dir) / "solutions" / run.label / f"{vid}.tum"
        write_tum_file(path, run.positions[vid].items(), origin_ecef)
        paths.append(path)
    return paths


def write_truth_tum(rec: Recording, out_dir: Path, origin_ecef: Vec | None = None) -> list[Path]:
    """truth/<vehicle>.tum in the same frame, the reference for `evo_ape tum truth/u1.tum ...`."""
    paths = []
    for v in rec.manifest.vehicles:
        truth = rec.truth(v.id)
        if truth:
            path = Path(out_dir) / "truth" / f"{v.id}.tum"
            write_tum_file(path, [(p.time, np.asarray(p.ecef_m)) for p in truth], origin_ecef)
            paths.append(path)
    return paths


def write_solution_formats(
    runs: Sequence[MethodRun], rec: Recording, out_dir: Path, formats: Collection[str]
) -> None:
    """The extra solution files `--format` asks for (`SOLUTION_FORMATS`), for every run: what
    `coplane eval` and `coplane fleet --out` write beside their CSVs."""
    if "tum" in formats:
        origin = tum_origin(rec)
        for run in runs:
            write_tum(run, out_dir, origin)
        write_truth_tum(rec, out_dir, origin)
    if "pos" in formats:
        from coplane.evaluate.rtklib_row import RTKLIB_METHOD  # imports the runner: only when asked

        for run in runs:
            if run.method != RTKLIB_METHOD:  # the rtklib row is RTKLIB's own solution, Q and all
                write_method_pos(run, out_dir, [str(rec.manifest.root)])
