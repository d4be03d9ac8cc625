"""A replay's schedule and how its steps are built, shared by the in-process evaluator and the
vehicle agents / fusion server, so the lockstep bus replay computes on the same inputs.

A vehicle is live from its first to its last observation epoch. Inside that span it reports at
every nominal epoch (a multiple of the interval), with an empty report where its receiver had no
epoch (an underpass, a dropped epoch), so that in lockstep the server never waits for a message
that will not come and the vehicle still gets a plane and a carried-through position.

`ReplaySetup` (from `replay_setup`) builds the `VehicleStep`s and the `FusionStep` and
`BaseCorrections` gives each epoch's DGNSS corrections. The step classes are imported where they
are used: the API imports this module for `fleet_id` and should not load the estimators.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from coplane.errors import ConfigError
from coplane.gtime import GpsTime
from coplane.recording.model import NavData, ObsEpoch, UwbRange
from coplane.recording.problems import RecordingError
from coplane.typing import AnyArray

if TYPE_CHECKING:
    from coplane.fgo.solve import Smoothers
    from coplane.gnss.dgnss import DgnssCorrections
    from coplane.gnss.epoch_solver import EpochSolverOptions
    from coplane.methods import MethodSpec
    from coplane.plane.config import PlaneConfig
    from coplane.recording.manifest import Manifest
    from coplane.recording.reader import Recording
    from coplane.roadmap import RoadMap
    from coplane.steps import FusionStep, FusionStepConfig, VehicleStep, VehicleStepConfig

DEFAULT_UWB_SIGMA_M = 0.3  # without a [uwb] table in the manifest


# A replay longer than this many nominal epochs is refused (a month at 1 Hz): the schedule lists
# every nominal epoch, so a corrupt span would otherwise exhaust memory.
MAX_REPLAY_EPOCHS = 31 * 86400


def nominal_grid(first: GpsTime, last: GpsTime, interval_s: float) -> Iterator[GpsTime]:
    """Every nominal epoch from `first` to `last`; refuses spans of more than MAX_REPLAY_EPOCHS."""
    t0 = first.round_to(interval_s)
    n = round((last.round_to(interval_s) - t0) / interval_s)
    if n > MAX_REPLAY_EPOCHS:
        raise RecordingError(
            f"observations span {first} to {last}: {n + 1} epochs of {interval_s} s, more than the "
            f"{MAX_REPLAY_EPOCHS} a replay allows; check the epoch time tags"
        )
    for k in range(n + 1):
        yield (t0 + k * interval_s).round_to(interval_s)


def vehicle_schedule(epochs: Sequence[ObsEpoch], interval_s: float) -> list[tuple[GpsTime, ObsEpoch | None]]:
    """(nominal time, the receiver epoch or None) for every nominal epoch of the vehicle's span."""
    if not epochs:
        return []
    by_t: dict[GpsTime, ObsEpoch] = {}
    for e in epochs:
        by_t.setdefault(e.time.round_to(interval_s), e)  # the reader already dropped duplicates
    return [(t, by_t.get(t)) for t in nominal_grid(epochs[0].time, epochs[-1].time, interval_s)]


def fleet_id(name: str) -> str:
    """A bus-safe fleet id ([A-Za-z0-9_-], at most 32 chars) from a recording's free-text name."""
    slug = "".join(c if (c.isascii() and c.isalnum()) or c in "-_" else "-" for c in name.strip())
    slug = "-".join(p for p in slug.split("-") if p)[:32].strip("-")
    return slug or "fleet"


def uwb_for_vehicle(
    ranges: Iterable[UwbRange],
    vehicle_id: str,
    times: Iterable[GpsTime],
    interval_s: float,
    tolerance: float = 0.1,
) -> dict[GpsTime, list[UwbRange]]:
    """The ranges `vehicle_id` measured (it is `from_id`), by the nominal epochs it reports at.

    A row belongs to the nearest nominal epoch within `tolerance` x interval (spec); a pair at most
    once per epoch (first row wins). The agent and the in-process evaluator both use this, so
    both send the same ranges.
    """
    wanted = set(times)
    out: dict[GpsTime, list[UwbRange]] = {}
    seen: set[tuple[GpsTime, tuple[str, str]]] = set()
    for r in ranges:
        if r.a != vehicle_id or r.b == vehicle_id:
            continue
        t = r.time.round_to(interval_s)
        if t not in wanted or abs(r.time - t) > tolerance * interval_s or (t, r.pair) in seen:
            continue
        seen.add((t, r.pair))
        out.setdefault(t, []).append(r)
    return out


def first_epoch(recording: Recording) -> GpsTime | None:
    """The fleet's first nominal epoch, reading one epoch per file (shared realtime origin)."""
    from coplane.recording.problems import Problems
    from coplane.recording.rinex_obs import iter_obs

    firsts = []
    for v in recording.manifest.vehicles:
        _, it = iter_obs(v.obs, Problems())
        e = next(it, None)
        if e is not None:
            firsts.append(e.time)
    return min(firsts).round_to(recording.manifest.interval_s) if firsts else None


def base_by_epoch(recording: Recording) -> dict[GpsTime, ObsEpoch]:
    """The reference station's epochs by nominal time (first wins), for DGNSS corrections."""
    out: dict[GpsTime, ObsEpoch] = {}
    for e in recording.base_epochs():
        out.setdefault(e.time.round_to(recording.manifest.interval_s), e)
    return out


@dataclass(frozen=True)
class ReplaySetup:
    """How every step of one replay is built, from the manifest and the run's options."""

    fleet: str
    method: MethodSpec
    vehicle_config: VehicleStepConfig
    fusion_config: FusionStepConfig
    use_dgnss: bool

    def vehicle_step(self, recording: Recording, vehicle_id: str) -> VehicleStep:
        from coplane.steps import VehicleStep

        v = recording.manifest.vehicle(vehicle_id)
        return VehicleStep(
            self.fleet, v.id, v.antenna_height_m, recording.nav, self.method, self.vehicle_config
        )

    def fusion_step(self, smoothers: Smoothers | None = None) -> FusionStep:
        """`smoothers`: where the factor graph's cluster smoothers run (`coplane.parallel`)."""
        from coplane.steps import FusionStep

        return FusionStep(self.fleet, self.method, self.fusion_config, smoothers)


def replay_setup(
    manifest: Manifest,
    method: MethodSpec | str,
    *,
    seed: int = 0,
    interruption: float = 0.0,
    dgnss: bool | None = None,
    plane_config: PlaneConfig | None = None,
    fleet: str | None = None,
    road_map: RoadMap | None = None,
    front_end: EpochSolverOptions | None = None,
) -> ReplaySetup:
    """The replay's setup. DGNSS is used when the recording has a base (`dgnss=None`); asking for
    it without one is a ConfigError. `fleet` overrides the id derived from the recording's name.
    `front_end`: the vehicles' GNSS front-end options (SPP, Doppler), the defaults when None."""
    from coplane.methods import get_method
    from coplane.steps import FusionStepConfig, VehicleStepConfig

    spec = get_method(method) if isinstance(method, str) else method
    use_dgnss = manifest.base is not None if dgnss is None else dgnss
    if use_dgnss and manifest.base is None:
        raise ConfigError(f"recording {manifest.name!r} has no [base]: cannot run with DGNSS")
    uwb_sigma = manifest.uwb.sigma_m if manifest.uwb else DEFAULT_UWB_SIGMA_M
    vcfg = VehicleStepConfig(uwb_sigma_m=uwb_sigma, seed=seed)
    if front_end is not None:
        vcfg.solver = front_end
    if plane_config is not None:
        vcfg.plane = plane_config
    vcfg.road_map = road_map
    return ReplaySetup(
        fleet=fleet or fleet_id(manifest.name),
        method=spec,
        vehicle_config=vcfg,
        fusion_config=FusionStepConfig(interruption, seed, manifest.interval_s),
        use_dgnss=use_dgnss,
    )


@dataclass
class BaseCorrections:
    """DGNSS corrections of a nominal epoch from the reference station (None without a base epoch)."""

    by_t: Mapping[GpsTime, ObsEpoch]
    position: AnyArray | None
    nav: NavData
    _last: tuple[GpsTime, DgnssCorrections | None] | None = field(default=None, repr=False)
    # every epoch's corrections once computed (`remembering`), for several runs over one recording,
    # up to `_memo_max` epochs
    _memo: dict[GpsTime, DgnssCorrections | None] | None = field(default=None, repr=False)
    _memo_max: int = field(default=0, repr=False)

    @classmethod
    def of(cls, recording: Recording, use_dgnss: bool) -> BaseCorrections:
        """Reads the base station's file only when `use_dgnss`."""
        base = recording.manifest.base
        if not use_dgnss or base is None:
            return cls({}, None, NavData())  # no corrections ever: the ephemerides are not needed
        return cls(base_by_epoch(recording), np.asarray(base.position_ecef_m), recording.nav)

    def remembering(self, max_epochs: int) -> BaseCorrections:
        """The same corrections, each epoch's kept once computed, for the first `max_epochs`
        epochs asked for (past them the rest are computed as before). Every run of `coplane eval`
        or the benchmark over one recording asks for every epoch; once the vehicles' front ends
        were remembered (`evaluate.front_ends.FrontEndMemo`), computing them (the base's
        satellites and their SPP residuals) was about a tenth of a method's run, and one epoch's
        take about 5 kB (one-off py-spy and tracemalloc looks at a simulated dense-urban drive,
        2026-12-02). Nothing downstream changes a `DgnssCorrections`, so the runs share them."""
        return BaseCorrections(self.by_t, self.position, self.nav, _memo={}, _memo_max=max_epochs)

    @property
    def remembered_epochs(self) -> int:
        """How many epochs' corrections are kept (`remembering`; 0 without)."""
        return len(self._memo) if self._memo is not None else 0

    def at(self, t: GpsTime) -> DgnssCorrections | None:
        """Computed once per epoch (several vehicles ask for the same one in a row)."""
        if self._last is not None and self._last[0] == t:
            return self._last[1]
        if self._memo is not None and t in self._memo:
            corr = self._memo[t]
        else:
            from coplane.gnss.epoch_solver import base_corrections

            b = self.by_t.get(t)
            corr = None
            if b is not None and self.position is not None:
                corr = base_corrections(b, self.position, self.nav)
            if self._memo is not None and len(self._memo) < self._memo_max:
                self._memo[t] = corr
        self._last = (t, corr)
        return corr
