"""Solution files other tools open: RTKLIB .pos (RTKPLOT, rtklib-py, ...)."""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from coplane import __version__
from coplane.geo import ecef_to_geodetic, enu_rotation
from coplane.gtime import GpsTime
from coplane.typing import Vec

# RTKLIB solution quality flags
Q_FIX, Q_FLOAT, Q_SBAS, Q_DGPS, Q_SINGLE, Q_PPP = 1, 2, 3, 4, 5, 6


@dataclass(frozen=True)
class PosRecord:
    time: GpsTime
    ecef: Vec
    covariance: Vec  # 3x3 ECEF
    quality: int
    n_sats: int


def _sq(v: float) -> float:
    """RTKLIB's signed square root for covariance terms."""
    return math.copysign(math.sqrt(abs(v)), v)


def write_pos(
    path: Path, records: Iterable[PosRecord], inputs: Iterable[str] = (), mode: str = "single"
) -> int:
    """Write RTKLIB's llh .pos layout (GPST calendar time); returns the number of records."""
    recs = list(records)
    path.parent.mkdir(parents=True, exist_ok=True)
    lines = [f"% program   : coplane {__version__}"]
    lines += [f"% inp file  : {p}" for p in inputs]
    lines += [
        f"% pos mode  : {mode}",
        "% (lat/lon/height=WGS84/ellipsoidal,Q=1:fix,2:float,3:sbas,4:dgps,5:single,6:ppp,ns=# of satellites)",
        "%  GPST                  latitude(deg) longitude(deg)  height(m)   Q  ns   sdn(m)   sde(m)   sdu(m)"
        "  sdne(m)  sdeu(m)  sdun(m) age(s)  ratio",
    ]
    for r in recs:
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
            f"{_sq(q[1, 0]):8.4f} {_sq(q[0, 2]):8.4f} {_sq(q[2, 1]):8.4f} {0.0:6.2f} {0.0:6.1f}"
        )
    path.write_text("\n".join(lines) + "\n")
    return len(recs)
