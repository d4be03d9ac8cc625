"""The RTKLIB reference row of `coplane eval` (method name "rtklib"): the standard tool beside ours.

RTKLIB 2.4.3 b34 (through pyrtklib, an optional dependency in the dev extra) post-processes each
vehicle's RINEX observation file of the recording directly with `postpos`, the engine of
rnx2rtkp/RTKPOST. It does not go through the node messages: it is RTKLIB's own SPP (broadcast
ephemeris, Klobuchar, Saastamoinen, its elevation weighting and chi-square/RAIM checks) on the same
raw data, so every Table I shows what the standard tool gets on that recording.

Mode: DGPS (code-differential kinematic against the recording's base at its known position) when
DGNSS is on, else single. RTKLIB's relative modes, DGPS included, only use a pseudorange whose
carrier phase is also present (rtkpos.c `validobs`: "if no phase observable, pseudorange is also
unusable"); the simulated recordings carry no carrier phase, so with them DGPS yields no
solution and `outsingle` makes RTKLIB output its single-point solution instead. The solutions'
quality flags are counted (`RtklibResult.quality`) and the note says which mode was really used.
"""

from __future__ import annotations

import math
import tempfile
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from coplane.evaluate.runner import MethodRun, lockstep_schedule
from coplane.recording.compressed import plain_file
from coplane.recording.problems import Problems
from coplane.recording.reader import Recording
from coplane.recording.trajectories import Q_NAMES, PosRecord, read_pos

RTKLIB_METHOD = "rtklib"

# prcopt_t fields copied from RTKLIB's prcopt_default (a fresh prcopt_t from pyrtklib is all zeros,
# which would e.g. reject every innovation with maxinno = 0)
_PRCOPT_SCALARS = (
    "armaxiter", "bdsmodear", "codesmooth", "dynamics", "elmaskar", "elmaskhold", "elmin", "freqopt",
    "glomodear", "initrst", "intpref", "ionoopt", "maxaveep", "maxgdop", "maxinno", "maxout",
    "maxtdiff", "minfix", "minlock", "mode", "modear", "navsys", "nf", "niter", "outsingle", "refpos",
    "rovpos", "sateph", "sbascorr", "sbassatsel", "sclkstab", "soltype", "syncsol", "thresslip",
    "tidecorr", "tropopt",
)  # fmt: skip
_PRCOPT_ARRAYS = {"eratio": 3, "err": 5, "prn": 6, "std": 3, "thresar": 6}
_SOLOPT_SCALARS = (
    "datum", "degf", "geoid", "height", "maxsolstd", "outhead", "outopt", "outvel", "posf", "solstatic",
    "sstat", "timef", "times", "timeu", "trace",
)  # fmt: skip


def rtklib_unavailable() -> str | None:
    """Why the RTKLIB row cannot run here (pyrtklib missing), or None when it can."""
    try:
        import pyrtklib  # noqa: F401
    except ImportError as exc:
        return f"pyrtklib is not importable ({exc}); install the dev extra (pip install -e '.[dev]') for the RTKLIB row"
    return None


@dataclass
class RtklibResult:
    run: MethodRun
    mode: str  # what was asked: "dgps" or "single"
    quality: dict[str, Counter[str]] = field(default_factory=dict)  # per vehicle: solutions by RTKLIB Q
    failures: dict[str, str] = field(default_factory=dict)  # vehicle -> why RTKLIB gave nothing

    @property
    def note(self) -> str:
        """One line for the console and accuracy.json: the mode asked and the solutions obtained."""
        total: Counter[str] = Counter()
        for q in self.quality.values():
            total.update(q)
        got = ", ".join(f"{n} {k}" for k, n in sorted(total.items())) or "no solutions"
        text = f"RTKLIB {self.mode} (pyrtklib postpos): {got}"
        if self.mode == "dgps" and not total.get("dgps"):
            text += " (no DGPS solution: RTKLIB 2.4.3 uses code only with carrier phase; single-point output)"
        if self.failures:
            text += "; failed: " + ", ".join(f"{v}: {r}" for v, r in sorted(self.failures.items()))
        return text


def rtklib_options(rec: Recording, dgps: bool, elevation_mask_deg: float) -> tuple[Any, Any]:
    """(prcopt, solopt) for this row's code modes, from RTKLIB's defaults; `rtk_reference` starts
    from the same options and switches to carrier-phase RTK."""
    import pyrtklib as rtk

    d, opt = rtk.prcopt_default, rtk.prcopt_t()
    for n in _PRCOPT_SCALARS:
        setattr(opt, n, getattr(d, n))
    for n, k in _PRCOPT_ARRAYS.items():
        dst, src = getattr(opt, n), getattr(d, n)
        for i in range(k):
            dst[i] = src[i]
    opt.mode = rtk.PMODE_DGPS if dgps else rtk.PMODE_SINGLE
    opt.navsys = rtk.SYS_GPS | rtk.SYS_CMP
    opt.nf = 1
    opt.elmin = math.radians(elevation_mask_deg)
    opt.sateph = rtk.EPHOPT_BRDC
    opt.ionoopt = rtk.IONOOPT_BRDC
    opt.tropopt = rtk.TROPOPT_SAAS
    opt.posopt[4] = 1  # RAIM FDE, as our SPP
    opt.outsingle = 1  # DGPS: output the single solution where there is no differential one
    if dgps:
        assert rec.manifest.base is not None
        opt.refpos = rtk.POSOPT_POS
        for i, v in enumerate(rec.manifest.base.position_ecef_m):
            opt.rb[i] = float(v)
    sd, sopt = rtk.solopt_default, rtk.solopt_t()
    for n in _SOLOPT_SCALARS:
        setattr(sopt, n, getattr(sd, n))
    sopt.sep[0] = sd.sep[0]
    sopt.posf = rtk.SOLF_XYZ
    sopt.times = rtk.TIMES_GPST
    sopt.timef = 0  # GPS week and seconds of week
    sopt.outhead = 1
    return opt, sopt


def postpos_files(paths: list[Path], directory: Path) -> list[str]:
    """`paths` as postpos reads them: RTKLIB takes plain RINEX only (it would shell out to crx2rnx
    and gzip), so each compressed one is decompressed into its own folder of `directory`."""
    return [str(plain_file(p, directory / f"input-{i}")) for i, p in enumerate(paths)]


def run_postpos(opt: Any, sopt: Any, files: list[str], out: Path) -> tuple[int, list[PosRecord]]:
    """RTKLIB postpos over `files` (rover, [base,] navigation) into `out`: its return code and the
    solutions read back (empty when it wrote none)."""
    import pyrtklib as rtk

    buf = rtk.Arr1Dchar(1024)
    for i, ch in enumerate(str(out)[:1023]):
        buf[i] = ch
    ret = rtk.postpos(
        rtk.gtime_t(), rtk.gtime_t(), 0.0, 0.0, opt, sopt, rtk.filopt_t(), files, len(files), buf, "", ""
    )
    return int(ret), read_pos(out, Problems()) if out.exists() else []


def process_recording(
    rec: Recording,
    dgnss: bool | None = None,
    vehicles: list[str] | None = None,
    elevation_mask_deg: float = 10.0,
) -> RtklibResult:
    """RTKLIB postpos on every vehicle's RINEX file; positions keyed by nominal epoch.

    DGNSS defaults to on when the recording has a base (as `coplane eval`). Needs pyrtklib.
    """
    use_dgnss = rec.manifest.base is not None if dgnss is None else bool(dgnss)
    if use_dgnss and rec.manifest.base is None:
        raise ValueError(f"recording {rec.manifest.name!r} has no [base]: cannot run RTKLIB DGPS")
    ids = vehicles or [v.id for v in rec.manifest.vehicles]
    opt, sopt = rtklib_options(rec, use_dgnss, elevation_mask_deg)
    dt = rec.manifest.interval_s
    run = MethodRun(RTKLIB_METHOD, 0.0)
    res = RtklibResult(run, "dgps" if use_dgnss else "single")
    t_start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="coplane-rtklib-") as tmp:
        for vid in ids:
            paths = [rec.manifest.vehicle(vid).obs]
            if use_dgnss:
                assert rec.manifest.base is not None
                paths.append(rec.manifest.base.obs)  # postpos: rover, base, then navigation
            files = postpos_files([*paths, *rec.manifest.nav_files], Path(tmp) / vid)
            t0 = time.perf_counter()
            ret, sols = run_postpos(opt, sopt, files, Path(tmp) / f"{vid}.pos")
            elapsed = time.perf_counter() - t0
            if ret != 0 or not sols:
                res.failures[vid] = f"postpos returned {ret} with {len(sols)} solutions"
            quality: Counter[str] = Counter()
            for r in sols:
                tn = r.time.round_to(dt)
                run.positions[vid][tn] = r.ecef
                run.covariances[vid][tn] = r.covariance
                quality[Q_NAMES.get(r.quality, str(r.quality))] += 1
            res.quality[vid] = quality
            run.solve_times_s.extend([elapsed / max(len(sols), 1)] * len(sols))
    run.wall_time_s = time.perf_counter() - t_start
    run.n_epochs = len(lockstep_schedule(rec, ids))
    return res


def evaluation_row(rec: Recording, dgnss: bool | None = None) -> tuple[MethodRun | None, str]:
    """For `coplane eval`: the RTKLIB run (None when skipped) and the line to print and record."""
    reason = rtklib_unavailable()
    if reason is not None:
        return None, f"rtklib row skipped: {reason}"
    try:
        res = process_recording(rec, dgnss)
    except (OSError, ValueError, RuntimeError) as exc:
        return None, f"rtklib row skipped: RTKLIB failed ({exc})"
    return res.run, res.note
