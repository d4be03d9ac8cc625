"""A reference trajectory for a moving receiver without truth: RTKLIB's carrier-phase RTK.

A real drive rarely comes with a surveyed trajectory, but a dual-frequency rover beside a reference
station does carry one where its carrier phase holds: RTKLIB's kinematic RTK resolves it to
centimetres where the ambiguities fix and to decimetres where they float. That is a different
technique (carrier phase) in a different program from everything coplane and the RTKLIB code row
compute, so the metre-level errors of code positioning can be measured against it.

An urban RTK solution can be wrong, so an epoch enters the reference only when two runs with
separate histories agree: RTKLIB's forward and backward filters (`soltype` 0 and 1) must both
have a fixed or float solution there, within `agree_m` of each other. The reference is the fixed
one where either fixed, else their mean. Epochs where the sky was too poor for RTK are missing, so
errors against it describe the easier part of a drive; `RtkReference.note` says how much it covers.
"""

from __future__ import annotations

import math
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from coplane.errors import ConfigError
from coplane.evaluate.rtklib_row import postpos_files, rtklib_options, rtklib_unavailable, run_postpos
from coplane.gtime import GpsTime
from coplane.recording.compressed import file_format
from coplane.recording.reader import Recording
from coplane.recording.trajectories import Q_FIX, Q_FLOAT
from coplane.typing import Vec


@dataclass
class RtkReference:
    """Reference positions (ECEF, antenna) of one receiver, keyed by nominal epoch."""

    vehicle: str
    positions: dict[GpsTime, Vec] = field(default_factory=dict)
    n_epochs: int = 0  # epochs either run solved at all
    n_fixed: int = 0  # reference epochs taken from a fixed solution
    disagreeing: int = 0  # both runs fixed or float there, but further apart than agree_m
    agree_m: float = 0.5
    # epochs where both runs fixed: how far apart they were (m); the strictest reference epochs,
    # e.g. for velocities from position differences (bench/moving_car_rtk.py)
    both_fixed_m: dict[GpsTime, float] = field(default_factory=dict)

    @property
    def note(self) -> str:
        """One line for the results: what the reference covers and how it was made."""
        return (
            f"reference: RTKLIB kinematic RTK (L1+L2, GPS+Galileo+BeiDou+QZSS, elevation mask 15 deg, "
            f"continuous ambiguity resolution), forward and backward runs agreeing within "
            f"{self.agree_m:g} m on {len(self.positions)} of {self.n_epochs} epochs ({self.n_fixed} "
            f"from a fixed solution; {self.disagreeing} epochs where they disagreed left out)"
        )


def rtk_reference(rec: Recording, vehicle: str | None = None, *, agree_m: float = 0.5) -> RtkReference:
    """RTKLIB's RTK reference for `vehicle` (the first by default) against the recording's base.

    Needs pyrtklib, a `[base]` with its position, and carrier phase on two frequencies in both
    files; raises ValueError when the recording has no base.
    """
    if rec.manifest.base is None:
        raise ValueError(f"recording {rec.manifest.name!r} has no [base]: no RTK reference")
    if not (math.isfinite(agree_m) and agree_m > 0.0):
        raise ValueError(f"agree_m must be a positive number of metres, got {agree_m!r}")
    import pyrtklib as rtk  # the optional dependency, once the inputs are known to be usable

    vid = vehicle or rec.manifest.vehicles[0].id
    runs: list[dict[GpsTime, tuple[Vec, int]]] = []
    with tempfile.TemporaryDirectory(prefix="coplane-rtk-") as tmp:
        paths = [rec.manifest.vehicle(vid).obs, rec.manifest.base.obs, *rec.manifest.nav_files]
        files = postpos_files(paths, Path(tmp))
        for soltype in (0, 1):  # forward, backward
            opt, sopt = rtklib_options(rec, True, 15.0)
            opt.mode = rtk.PMODE_KINEMA
            opt.nf = 2
            opt.navsys = rtk.SYS_GPS | rtk.SYS_GAL | rtk.SYS_CMP | rtk.SYS_QZS
            opt.modear = rtk.ARMODE_CONT
            opt.soltype = soltype
            _, sols = run_postpos(opt, sopt, files, Path(tmp) / f"{vid}-{soltype}.pos")
            runs.append({r.time.round_to(rec.manifest.interval_s): (r.ecef, r.quality) for r in sols})
    forward, backward = runs
    ref = RtkReference(vid, agree_m=agree_m, n_epochs=len(forward.keys() | backward.keys()))
    for t in sorted(forward.keys() & backward.keys()):
        (xf, qf), (xb, qb) = forward[t], backward[t]
        if qf not in (Q_FIX, Q_FLOAT) or qb not in (Q_FIX, Q_FLOAT):
            continue
        apart = float(np.linalg.norm(xf - xb))
        if qf == qb == Q_FIX:
            ref.both_fixed_m[t] = apart
        if apart > agree_m:
            ref.disagreeing += 1
            continue
        ref.positions[t] = xf if qf == Q_FIX else xb if qb == Q_FIX else (xf + xb) / 2.0
        ref.n_fixed += int(Q_FIX in (qf, qb))
    return ref


def use_rtk_truth(rec: Recording) -> str:
    """Replace every vehicle's truth by its RTK reference (`--truth rtk` of `coplane eval`,
    `coplane fleet` and the API); the line that says what it covers. ConfigError, with the reason,
    when no reference can be made."""
    if rec.manifest.base is None:
        raise ConfigError(f"recording {rec.manifest.name!r} has no [base]: no RTK reference")
    if (reason := rtklib_unavailable()) is not None:
        raise ConfigError(f"the RTK reference needs RTKLIB: {reason}")
    notes = []
    for v in rec.manifest.vehicles:
        if file_format(v.obs) != "rinex":
            raise ConfigError(f"{v.obs}: the RTK reference needs RINEX observations (RTKLIB postpos)")
        ref = rtk_reference(rec, v.id)
        rec.use_truth(v.id, ref.positions)
        notes.append(f"{v.id}: {ref.note}")
    if not any(rec.truth_at(v.id) for v in rec.manifest.vehicles):
        raise ConfigError(
            f"recording {rec.manifest.name!r}: RTKLIB's RTK gave no reference epoch for any vehicle "
            "(it needs carrier phase on two frequencies in the vehicles' and the base's RINEX)"
        )
    return "errors against RTKLIB's RTK, not a surveyed truth: " + "; ".join(notes)
