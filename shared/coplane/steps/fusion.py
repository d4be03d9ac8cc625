"""`FusionStep`: the server's epoch, node messages in, the fleet's solution message out (pure).

It turns the node messages of one epoch into the estimator's `EpochInput` (only satellites the
vehicle used, one range per pair, the ranging-interruption experiment applied by time so a
restarted server decides alike), steps the method's estimator and wraps its estimates with what
the vehicles reported (plane status, satellites) into a `SolutionMessage`. No I/O: `coplane eval`
and the fusion server call the same object (docs/architecture.md).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from coplane.components import UnionFind
from coplane.estimation.contract import (
    EpochInput,
    PlaneObs,
    RangeObs,
    VehicleEpochInput,
    VelocityObs,
)
from coplane.gtime import GpsTime
from coplane.messages import NodeMessage, SolutionMessage, VehicleState
from coplane.methods import MethodSpec, interrupt_range
from coplane.steps.wire import (
    cov9,
    doppler_observed,
    epoch_time,
    plane_summary,
    pseudorange_columns,
    tuple3,
)

if TYPE_CHECKING:
    from coplane.fgo.solve import Smoothers  # imports GTSAM: only for the annotation


@dataclass
class FusionStepConfig:
    interruption_rate: float = 0.0  # paper 5.3: share of ranges removed per pair (seeded)
    interruption_seed: int = 0
    interval_s: float = 1.0  # the epoch index for interruption comes from time, not a counter
    # at most this many ranges per vehicle and epoch, the shortest kept: in a dense city every
    # vehicle hears dozens within UWB reach, and a cluster whose range graph is that dense costs
    # the smoother time and memory that grow faster than its size (docs/performance-scale.md)
    max_ranges_per_vehicle: int = 8
    max_cluster_vehicles: int = 16  # and no cluster of ranged vehicles beyond this (bounded_ranges)


def bounded_ranges(
    ranges: dict[tuple[str, str], RangeObs], per_vehicle: int, cluster_max: int
) -> dict[tuple[str, str], RangeObs]:
    """The pairs kept so that each vehicle has at most `per_vehicle` ranges and no cluster of
    vehicles linked by kept ranges has more than `cluster_max` members (0: no bound).

    Why: in a dense city every vehicle hears dozens of others within UWB reach and the range graph
    joins the whole fleet into one cluster, whose solve costs time and memory that grow much
    faster than its size (docs/performance-scale.md). Cooperation is local: the nearest few peers
    carry almost all of the benefit. Pairs are taken like Kruskal's algorithm, shortest first, ties
    by pair: a function of the epoch's ranges alone (fusion servers that see the same vehicles
    agree), and a fleet within both bounds keeps every range. The estimator's clusters join the
    ranges of its whole window, so one can still grow past `cluster_max` when the nearest peers
    change within it."""
    degree: dict[str, int] = {}
    for a, b in ranges:
        degree[a] = degree.get(a, 0) + 1
        degree[b] = degree.get(b, 0) + 1
    small = per_vehicle <= 0 or all(n <= per_vehicle for n in degree.values())
    if small and (cluster_max <= 0 or len(degree) <= cluster_max):
        return ranges
    uf = UnionFind(degree)
    used: dict[str, int] = {}
    out: dict[tuple[str, str], RangeObs] = {}
    for pair, r in sorted(ranges.items(), key=lambda kv: (kv[1].range_m, kv[0])):
        a, b = pair
        if per_vehicle > 0 and (used.get(a, 0) >= per_vehicle or used.get(b, 0) >= per_vehicle):
            continue
        if not uf.union_within(a, b, cluster_max):
            continue
        out[pair] = r
        used[a] = used.get(a, 0) + 1
        used[b] = used.get(b, 0) + 1
    return out


class FusionStep:
    """The server's epoch: node messages -> factor-graph inputs -> solution message (pure)."""

    def __init__(
        self,
        fleet: str,
        method: MethodSpec,
        config: FusionStepConfig | None = None,
        smoothers: Smoothers | None = None,
    ) -> None:
        self.fleet = fleet
        self.method = method
        self.config = config or FusionStepConfig()
        self.estimator = method.build_estimator(smoothers)
        self.seq = 0

    @property
    def workers(self) -> tuple[int, int]:
        """(processes solving the estimator's clusters, how many died); (1, 0) for a filter."""
        got = getattr(self.estimator, "workers", None)
        return got if isinstance(got, tuple) else (1, 0)

    def close(self) -> None:
        """Stop what the estimator runs besides this process (the factor graph's cluster workers)."""
        close = getattr(self.estimator, "close", None)
        if close is not None:
            close()

    def inputs(self, t: GpsTime, messages: Mapping[str, NodeMessage]) -> EpochInput:
        vehicles: dict[str, VehicleEpochInput] = {}
        for vid in sorted(messages):
            vehicles[vid] = self._vehicle_input(t, messages[vid])
        kept = self.epoch_ranges(t, messages)
        return EpochInput(t, vehicles, tuple(kept[k] for k in sorted(kept)))

    def epoch_ranges(
        self, t: GpsTime, messages: Mapping[str, NodeMessage]
    ) -> dict[tuple[str, str], RangeObs]:
        """The ranges the estimator gets at `t`: one per pair of reporting vehicles, the
        ranging-interruption experiment applied, bounded per vehicle and per cluster
        (`bounded_ranges`). A function of the messages alone, so two fusion servers that see the
        same vehicles pick the same ranges (regions: docs/scale.md)."""
        ranges: dict[tuple[str, str], RangeObs] = {}
        for vid in sorted(messages):
            for r in messages[vid].ranges:
                if r.to not in messages:
                    continue
                pair = (vid, r.to) if vid < r.to else (r.to, vid)
                if pair in ranges:
                    continue  # a pair at most once per epoch (spec); first reporter wins
                k = round(t.seconds / self.config.interval_s)  # same decision after a server restart
                if interrupt_range(pair, k, self.config.interruption_rate, self.config.interruption_seed):
                    continue
                ranges[pair] = RangeObs(pair[0], pair[1], r.range_m, r.sigma_m)
        return bounded_ranges(ranges, self.config.max_ranges_per_vehicle, self.config.max_cluster_vehicles)

    def _vehicle_input(self, t: GpsTime, m: NodeMessage) -> VehicleEpochInput:
        vel = None
        if m.velocity is not None:
            vel = VelocityObs(
                np.array(m.velocity.velocity_ecef_mps), self.method.velocity_sigma_mps, m.velocity.standstill
            )
        plane = None
        if m.plane is not None and m.plane.status != "unavailable":
            assert (
                m.plane.normal is not None and m.plane.d_antenna_m is not None and m.plane.sigma_m is not None
            )
            plane = PlaneObs(np.array(m.plane.normal), m.plane.d_antenna_m, m.plane.sigma_m, m.plane.status)
        return VehicleEpochInput(
            vehicle_id=m.vehicle_id,
            time=t,
            pseudoranges=pseudorange_columns(m),
            velocity=vel,
            plane=plane,
            spp_position=np.array(m.spp.position_ecef_m) if m.spp.position_ecef_m is not None else None,
            clock_drift_mps=m.velocity.clock_drift_mps if m.velocity is not None else None,
            antenna_height_m=m.antenna_height_m,
            doppler_observed=doppler_observed(m),
        )

    def solve(
        self, t: GpsTime, messages: Mapping[str, NodeMessage], missing: Iterable[str] = ()
    ) -> SolutionMessage:
        sol = self.estimator.step(self.inputs(t, messages))
        states = []
        for vid in sorted(sol.estimates):
            est = sol.estimates[vid]
            msg = messages[vid]
            states.append(
                VehicleState(
                    vehicle_id=vid,
                    position_ecef_m=tuple3(est.position_m),
                    covariance_m2=cov9(est.covariance_m2),
                    clocks_s=dict(est.clocks_s),
                    antenna_height_m=msg.antenna_height_m,
                    n_pseudoranges=est.n_pseudoranges,
                    n_ranges=est.n_ranges,
                    plane_used=est.plane_used,
                    plane_status=msg.plane.status if msg.plane is not None else None,
                    plane=plane_summary(msg.plane),
                    has_gnss_fix=est.has_gnss_fix,
                    n_satellites=sum(msg.satellites.used),
                    spp_ok=msg.spp.ok,
                    dgnss_age_s=msg.spp.dgnss_age_s,
                    excluded_satellites=list(est.excluded_satellites),
                    raim_excluded=list(msg.spp.excluded),
                    hdop=msg.spp.hdop,
                    vdop=msg.spp.vdop,
                )
            )
        out = SolutionMessage(
            fleet=self.fleet,
            method=self.method.name,
            seq=self.seq,
            epoch=epoch_time(t),
            vehicles=states,
            solve_time_s=sol.solve_time_s,
            factor_counts=dict(sol.factor_counts),
            missing=sorted(missing),
            oldest_node_sent_unix_s=min(
                (m.sent_unix_s for m in messages.values() if m.sent_unix_s is not None), default=None
            ),
        )
        self.seq += 1
        return out
