"""Non-CP baseline (paper Table I "Non-CP"): one extended Kalman filter per vehicle.

The paper ran RTKLIB's EKF; this is the same textbook filter on our node messages, so it sees
exactly the pseudoranges (weighting, DGNSS corrections, RAIM exclusions) and Doppler velocity the
factor graph sees. The filter itself (state, noise, gate) is `fleet_filter.FleetFilter`;
equations, noise values and the gate are in docs/methods.md.
"""

from __future__ import annotations

from collections import Counter

from coplane.baselines.fleet_filter import EkfConfig, FleetFilter
from coplane.baselines.measurements import VehicleMeasurements, vehicle_measurements
from coplane.baselines.rows import Rows
from coplane.baselines.skeleton import BaselineEstimator, EpochOutcome
from coplane.estimation.contract import VehicleEstimate, left_out
from coplane.estimation.validate import ValidEpoch
from coplane.gtime import GpsTime


def gate_pseudoranges(
    filt: FleetFilter, m: VehicleMeasurements, t: GpsTime, rejected: Counter[str]
) -> VehicleMeasurements:
    """The vehicle's pseudoranges that pass the innovation gate.

    If more than `divergence_fraction` of at least `divergence_min` fail, the prediction is what
    is wrong, not the measurements: the vehicle restarts from its SPP and is gated again. Right
    after a (re)start the state comes from these very measurements, so if the gate still rejects
    that many, all are kept.
    """
    cfg = filt.config
    for _ in range(2):
        rows = Rows(len(filt.x))
        filt.pseudorange_rows(rows, m)
        g = filt.gate(rows)
        if not (len(m) >= cfg.divergence_min and len(g.rejected) > cfg.divergence_fraction * len(m)):
            rejected["pseudorange_gate"] += len(g.rejected)
            return m.subset(g.accepted)
        if filt.started.get(m.vehicle_id) == t:
            return m
        if m.spp is None:
            rejected["pseudorange_gate"] += len(g.rejected)
            return m.subset(g.accepted)
        filt.init_vehicle(m, t)
        rejected["reinit"] += 1
    return m


def vehicle_estimate(
    filt: FleetFilter, vid: str, t: GpsTime, given: VehicleMeasurements, used: VehicleMeasurements
) -> VehicleEstimate:
    """The filter's state of `vid`, with `used` the pseudoranges of `given` it applied."""
    n_pr = len(used)
    return VehicleEstimate(
        vehicle_id=vid,
        time=t,
        position_m=filt.position(vid),
        covariance_m2=filt.position_cov(vid),
        clocks_s=filt.clocks_s(vid),
        n_pseudoranges=n_pr,
        plane_used=False,
        has_gnss_fix=n_pr >= filt.config.min_fix_pseudoranges,
        excluded_satellites=left_out(given.sats, used.sats),
    )


class NonCpEkf(BaselineEstimator):
    """Estimator: an independent EKF per vehicle (no cooperation), driven by the fleet epoch.

    With `apply_pseudoranges=False` the filters stop before their pseudorange update (prediction,
    clock handling, gating, velocity and drift only) and leave the gated pseudoranges of the epoch
    in `gated`: the per-vehicle priors of the GAMP baseline.
    """

    def __init__(self, config: EkfConfig | None = None, apply_pseudoranges: bool = True) -> None:
        super().__init__()
        self.config = config or EkfConfig()
        self.apply_pseudoranges = apply_pseudoranges
        self.filters: dict[str, FleetFilter] = {}
        self.gated: dict[str, VehicleMeasurements] = {}

    def solve(self, valid: ValidEpoch, out: EpochOutcome) -> None:
        t = valid.time
        self.gated = {}
        for vid, v in valid.vehicles.items():
            try:
                est = self._vehicle_step(vehicle_measurements(v), t, out.rejected, out.counts)
            except Exception as exc:  # never raise on data: drop the filter, restart
                self.filters.pop(vid, None)
                self.gated.pop(vid, None)
                out.rejected["filter_failure"] += 1
                est = f"filter failure ({type(exc).__name__}): restarts next epoch"
            if isinstance(est, str):
                out.skipped[vid] = est
            else:
                out.estimates[vid] = est
        for vid in sorted(self.filters):  # vehicles gone for long: forget their filter
            f = self.filters[vid]
            f.drop_stale(t)
            if not f.vehicles():
                del self.filters[vid]
        out.n_clusters = len(out.estimates)

    def _vehicle_step(
        self, m: VehicleMeasurements, t: GpsTime, rejected: Counter[str], counts: Counter[str]
    ) -> VehicleEstimate | str:
        vid = m.vehicle_id
        filt = self.filters.get(vid)
        if filt is None:
            filt = FleetFilter(self.config)
        filt.predict(t)
        reason = filt.prepare_vehicle(m, t, rejected)
        if reason is not None:
            return reason
        self.filters[vid] = filt
        est, self.gated[vid] = ekf_update_vehicle(filt, m, t, rejected, counts, self.apply_pseudoranges)
        return est


def ekf_update_vehicle(
    filt: FleetFilter,
    m: VehicleMeasurements,
    t: GpsTime,
    rejected: Counter[str],
    counts: Counter[str],
    apply_pseudoranges: bool = True,
) -> tuple[VehicleEstimate, VehicleMeasurements]:
    """Gate and apply one vehicle's pseudoranges, velocity and drift (a restart on failure).

    Returns the estimate and the pseudoranges that passed the gate (applied or not).
    """
    vid = m.vehicle_id
    good = gate_pseudoranges(filt, m, t, rejected)
    rows = Rows(len(filt.x))
    if apply_pseudoranges:
        filt.pseudorange_rows(rows, good)
    keep = list(range(len(rows.groups)))
    n_pr_groups = len(keep)
    filt.velocity_rows(rows, m)
    g = filt.gate(rows, range(n_pr_groups, len(rows.groups)))
    keep += g.accepted
    for i in g.rejected:
        rejected[f"{rows.groups[i][1]}_gate"] += 1
    if not filt.update(rows, keep):
        rejected["update_failure"] += 1
        filt.init_vehicle(m, t)
        keep = []
        good = good.subset([])
    n_pr = len(good)
    if n_pr:
        filt.last_gnss[vid] = t
    for i in keep:
        counts[rows.groups[i][1]] += 1
    return vehicle_estimate(filt, vid, t, m, good), good
