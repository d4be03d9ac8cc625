"""Code DGNSS (paper eq. 19): per-satellite pseudorange corrections from a base at a known point.

The correction is computed at the base's own epoch tag from the base's own emission-time
satellite states (range minus geometry at that time), so rover and base epochs milliseconds apart
are never differenced raw (the satellite moves up to ~800 m/s in range). It contains ionosphere,
troposphere, orbit and satellite-clock-model errors and TGD; the base receiver clock is removed
per constellation (median) so corrections are metre-level numbers a person can read and that can
be sent over the bus. The rover then solves  P - delta = |p - p_s| + b - c*dts  (spp.solve_spp
with corrections_m): the remaining rover clock absorbs whatever base clock is left.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from coplane.gnss.constants import C
from coplane.gnss.geometry import sky_view
from coplane.gnss.measurements import PreparedEpoch
from coplane.gtime import GpsTime
from coplane.typing import Vec


@dataclass(frozen=True)
class DgnssOptions:
    elevation_mask_deg: float = 5.0
    max_abs_correction_m: float = 150.0  # after removing the base clock; larger means a bad base obs


@dataclass
class DgnssCorrections:
    time: GpsTime  # the base's exact tag
    corrections_m: dict[str, float] = field(default_factory=dict)
    base_clock_m: dict[str, float] = field(default_factory=dict)
    rejected: dict[str, str] = field(default_factory=dict)


def dgnss_corrections(
    base: PreparedEpoch, base_position_ecef: Vec, options: DgnssOptions | None = None
) -> DgnssCorrections:
    """Corrections delta_s = P_base - (|p_base - p_s|_sagnac - c*dts), base clock removed."""
    opt = options or DgnssOptions()
    p = np.asarray(base_position_ecef, dtype=float)
    raw: dict[str, float] = {}
    out = DgnssCorrections(base.time)
    if not base.sats:
        return out
    view = sky_view(np.array([m.state.pos for m in base.sats]), p)
    mask = math.radians(opt.elevation_mask_deg)
    for m, rng, el in zip(base.sats, view.range_m, view.el_rad, strict=True):
        if el < mask:
            out.rejected[m.sat] = f"elevation {math.degrees(el):.1f} deg below mask at the base"
            continue
        raw[m.sat] = m.pseudorange_m - (float(rng) - C * m.state.clock_s)
    for sys in sorted({s[0] for s in raw}):
        vals = np.array([v for s, v in raw.items() if s[0] == sys])
        clk = float(np.median(vals))
        out.base_clock_m[sys] = clk
        for s, v in raw.items():
            if s[0] != sys:
                continue
            d = v - clk
            if abs(d) > opt.max_abs_correction_m:
                out.rejected[s] = f"correction {d:.1f} m beyond {opt.max_abs_correction_m} m"
            else:
                out.corrections_m[s] = d
    return out
