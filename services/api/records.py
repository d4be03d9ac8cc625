"""What the API keeps of each vehicle: its latest state, and its track as points converted once.

`FleetState` (state.py) takes the bus messages and holds these; `views` serves them. A point keeps
only what the views show, and shares what repeats (empty tuples, the plane source's strings), since
`history_per_vehicle` of them are held per vehicle (about 1.1 kB each, tests/api/test_api_state.py).
"""

from __future__ import annotations

from collections import Counter, deque
from dataclasses import dataclass, field
from typing import get_args

from coplane.gtime import GpsTime
from coplane.messages import PlaneSourceName, VehicleCounters, VehicleState, plane_source
from coplane.typing import Mat

Vec3 = tuple[float, float, float]

# one string object per plane source, shared by every track point that names it
PLANE_SOURCES: dict[str, PlaneSourceName] = {s: s for s in get_args(PlaneSourceName)}


@dataclass(slots=True)
class StoredPoint:
    """One track point as taken, in every frame a view serves (converted once, not per request)."""

    t: GpsTime
    ecef: Vec3
    llh: Vec3  # degrees, degrees, metres
    enu: Vec3
    cov: tuple[float, ...] | None
    plane_status: str | None
    error_h: float | None
    # why the point is as good as it is: satellites the agent used and the estimator kept, those
    # each left out (empty tuples shared, as most epochs leave none out), the fix's VDOP
    n_satellites: int = 0
    n_pseudoranges: int = 0
    excluded: tuple[str, ...] = ()
    raim_excluded: tuple[str, ...] = ()
    vdop: float | None = None
    error_v: float | None = None
    gnss_fix: bool = True  # the epoch's own pseudoranges fixed it (False: motion, ranges or plane)
    dgnss_age: float | None = None  # age of the DGNSS corrections the agent's fix used (None: none)
    # what else held it: ranges to other vehicles, a road plane (and where the plane came from: one
    # of the PLANE_SOURCES strings, shared, not a copy per point), the fix's HDOP
    n_ranges: int = 0
    plane_used: bool = False
    plane_source: PlaneSourceName | None = None
    hdop: float | None = None


@dataclass
class StoredVehicle:
    """One vehicle: its latest state (None until a solution), liveliness, counters and track."""

    vid: str
    track: deque[StoredPoint]
    state: VehicleState | None = None
    method: str | None = None
    seq: int | None = None
    t: GpsTime | None = None
    received: float | None = None
    llh: Vec3 | None = None
    enu: Vec3 | None = None
    cov_enu: Mat | None = None
    error: tuple[float, float] | None = None
    online: bool = False
    server_online: bool | None = None
    counters: VehicleCounters | None = None
    plane_counts: Counter[str] = field(default_factory=Counter)
    plane_t: GpsTime | None = None


def stored_point(
    vs: VehicleState, t: GpsTime, llh: Vec3, enu: Vec3, err: tuple[float, float] | None
) -> StoredPoint:
    """The track point of one solved vehicle-epoch; `err`: (horizontal, signed vertical) against the
    truth, None without one."""
    source = plane_source(vs.plane)
    return StoredPoint(
        t=t,
        ecef=vs.position_ecef_m,
        llh=llh,
        enu=enu,
        cov=tuple(vs.covariance_m2) if vs.covariance_m2 is not None else None,
        plane_status=vs.plane_status,
        error_h=err[0] if err else None,
        n_satellites=vs.n_satellites,
        n_pseudoranges=vs.n_pseudoranges,
        excluded=tuple(vs.excluded_satellites) if vs.excluded_satellites else (),
        raim_excluded=tuple(vs.raim_excluded) if vs.raim_excluded else (),
        vdop=vs.vdop,
        error_v=err[1] if err else None,
        gnss_fix=vs.has_gnss_fix,
        dgnss_age=vs.dgnss_age_s,
        n_ranges=vs.n_ranges,
        plane_used=vs.plane_used,
        plane_source=None if source is None else PLANE_SOURCES[source],
        hdop=vs.hdop,
    )
