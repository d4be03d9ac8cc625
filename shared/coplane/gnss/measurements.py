"""One epoch's satellites made ready for the models: ephemeris state, raw code/Doppler, TGD.

SPP, Doppler velocity, DGNSS and the factor graph all start from the same `SatMeasurement`s, so
satellite positions are computed once per receiver epoch (the expensive part of an epoch).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

from coplane.gnss.constants import WAVELENGTH
from coplane.gnss.ephemeris import SatState, satellite_states, tgd_m
from coplane.gtime import GpsTime
from coplane.recording.model import NavData, ObsEpoch


@dataclass(frozen=True, slots=True)
class SatMeasurement:
    """A tracked satellite with a usable broadcast ephemeris at this epoch."""

    sat: str
    state: SatState
    pseudorange_m: float
    doppler_hz: float
    cn0_dbhz: float
    tgd_m: float

    @property
    def system(self) -> str:
        return self.sat[0]

    @property
    def range_rate_mps(self) -> float:
        """Doppler as range rate (RINEX sign: positive Doppler means approaching)."""
        return -WAVELENGTH[self.system] * self.doppler_hz


@dataclass(frozen=True, slots=True)
class PreparedEpoch:
    time: GpsTime
    sats: tuple[SatMeasurement, ...]
    dropped: tuple[tuple[str, str], ...]  # (sat, reason) for satellites that cannot be used
    # every satellite's emission-frame position (n, 3) and system, read-only: SPP, the Doppler
    # rows and the node message view the whole epoch from one position and take their subsets,
    # so `geometry.sky_view`'s and `broadcast_delays`' caches serve all three
    sat_pos: np.ndarray = field(init=False, repr=False, compare=False)
    systems: tuple[str, ...] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        pos = np.array([m.state.pos for m in self.sats], dtype=float).reshape(-1, 3)
        pos.flags.writeable = False
        object.__setattr__(self, "sat_pos", pos)
        object.__setattr__(self, "systems", tuple(m.sat[0] for m in self.sats))

    def by_sat(self) -> dict[str, SatMeasurement]:
        return {m.sat: m for m in self.sats}


def prepare_epoch(epoch: ObsEpoch, nav: NavData, systems: Iterable[str] = ("G", "C")) -> PreparedEpoch:
    """Satellite states at emission time for every satellite with a valid pseudorange."""
    wanted = set(systems)
    pr: dict[str, float] = {}
    dropped: list[tuple[str, str]] = []
    for s in epoch.sats:
        if s.sat[0] not in wanted:
            continue
        if not math.isfinite(s.pseudorange_m):
            dropped.append((s.sat, "no pseudorange"))
            continue
        pr[s.sat] = s.pseudorange_m
    states = satellite_states(nav, epoch.time, pr)
    out: list[SatMeasurement] = []
    obs = epoch.by_sat()
    for sat in sorted(pr):
        st = states.get(sat)
        if st is None:
            dropped.append((sat, "no usable ephemeris"))
            continue
        if not math.isfinite(st.clock_s + sum(st.pos.tolist())):  # one test for all four values
            dropped.append((sat, "ephemeris gave non-finite state"))
            continue
        o = obs[sat]
        out.append(SatMeasurement(sat, st, o.pseudorange_m, o.doppler_hz, o.cn0_dbhz, tgd_m(st.eph)))
    return PreparedEpoch(epoch.time, tuple(out), tuple(dropped))
