"""The two pure objects every path shares (design principle 1): no I/O, deterministic.

`VehicleStep` is one vehicle's epoch: SPP + Doppler velocity (DGNSS when corrections are given),
the road plane from the fleet's solved positions (paper Sec. III) and the node message.
`FusionStep` is the server's epoch: node messages -> factor-graph inputs -> fleet solution.
`coplane eval` calls them in-process, the Zenoh services call them over the bus; both exchange the
same pydantic messages, so a lockstep replay over the bus reproduces the in-process positions.
"""

from __future__ import annotations

import math
import zlib
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from coplane.estimation.contract import (
    EpochInput,
    PlaneObs,
    PseudorangeObs,
    RangeObs,
    VehicleEpochInput,
    VelocityObs,
)
from coplane.geo import up_vector
from coplane.gnss.dgnss import DgnssCorrections
from coplane.gnss.epoch_solver import EpochResult, EpochSolverOptions, solve_epoch
from coplane.gnss.geometry import broadcast_delays, sky_view
from coplane.gnss.weighting import pseudorange_sigma_m, standalone_pseudorange_sigma_m
from coplane.gtime import GpsTime
from coplane.messages import (
    EpochTime,
    NodeMessage,
    PlaneReport,
    PlaneSummary,
    RangeReport,
    SatelliteReport,
    SolutionMessage,
    SppReport,
    VehicleState,
    VelocityReport,
)
from coplane.methods import MethodSpec, interrupt_range
from coplane.plane.config import PlaneConfig
from coplane.plane.detect import PlaneStatus, RoadPlane, construct_plane, offset_sigma_m
from coplane.plane.history import PositionHistory
from coplane.recording.model import NavData, ObsEpoch, UwbRange

Vec = NDArray[Any]

_STATUS_NAME = {
    PlaneStatus.AVAILABLE: "available",
    PlaneStatus.AVAILABLE_AFTER_FE: "available-after-fe",
    PlaneStatus.UNAVAILABLE: "unavailable",
}


def epoch_time(t: GpsTime) -> EpochTime:
    return EpochTime(week=t.week, tow=t.tow)


def gps_time(e: EpochTime) -> GpsTime:
    return GpsTime(e.week, e.tow)


def _tuple3(v: Vec) -> tuple[float, float, float]:
    return (float(v[0]), float(v[1]), float(v[2]))


def _cov9(c: Vec) -> list[float] | None:
    c = np.asarray(c, dtype=float)
    return [float(x) for x in c.reshape(9)] if np.all(np.isfinite(c)) else None


def stable_seed(*parts: int | str) -> list[int]:
    """A seed sequence that does not depend on Python's per-process hash randomisation."""
    return [zlib.crc32(p.encode()) if isinstance(p, str) else int(p) & 0xFFFFFFFF for p in parts]


@dataclass
class VehicleStepConfig:
    solver: EpochSolverOptions = field(default_factory=EpochSolverOptions)
    plane: PlaneConfig = field(default_factory=PlaneConfig)
    uwb_sigma_m: float = 0.3
    seed: int = 0


class VehicleStep:
    """One vehicle: measurements + the fleet's solved positions -> node message (pure)."""

    def __init__(
        self,
        fleet: str,
        vehicle_id: str,
        antenna_height_m: float,
        nav: NavData,
        method: MethodSpec,
        config: VehicleStepConfig | None = None,
    ) -> None:
        self.fleet = fleet
        self.vehicle_id = vehicle_id
        self.antenna_height_m = antenna_height_m
        self.nav = nav
        self.method = method
        self.config = config or VehicleStepConfig()
        pc = self.config.plane
        if not method.plane_fault_exclusion:
            pc = replace(pc, fault_exclusion=False)
        self.plane_config = pc
        self.history = PositionHistory(pc)
        self.seq = 0
        self.first_epoch: GpsTime | None = None
        self._last_fused: tuple[GpsTime, Vec] | None = None
        self._last_spp: Vec | None = None

    # -- the fleet's solution feeds the plane history (paper eq. 2) --------------------------
    def ingest(self, solution: SolutionMessage) -> None:
        """Add a fleet solution to the plane history.

        Solutions of epochs before this vehicle's first epoch are ignored: a vehicle joins the
        cooperation when it starts reporting. Over the bus a late joiner cannot know what was
        solved before it subscribed, so the in-process run follows the same rule and both paths
        stay identical.
        """
        t = gps_time(solution.epoch)
        if self.first_epoch is None or t < self.first_epoch:
            return
        states = [
            v for v in solution.vehicles if self.method.planes != "self" or v.vehicle_id == self.vehicle_id
        ]
        if states and self.method.planes != "none":  # no plane, no history to keep
            self.history.add_many(
                [v.vehicle_id for v in states],
                t.seconds,
                [v.position_ecef_m for v in states],
                [v.antenna_height_m for v in states],
                [_sigma_up(v) for v in states],
            )
        for v in states:
            if v.vehicle_id == self.vehicle_id:
                self._last_fused = (t, np.asarray(v.position_ecef_m, dtype=float))

    # -- one epoch ---------------------------------------------------------------------------
    def front_end(
        self, t: GpsTime, epoch: ObsEpoch | None, corrections: DgnssCorrections | None = None
    ) -> EpochResult:
        """SPP and Doppler of this receiver's epoch: its own data only, nothing from the fleet.

        SPP starts from this receiver's previous fix (the fused position would tie the GNSS front
        end to the fusion step), so the front end can run ahead, e.g. while the server solves the
        previous epoch. Call once per epoch, in order, before `process`.
        """
        ep = epoch if epoch is not None else ObsEpoch(t, ())
        res = solve_epoch(ep, self.nav, corrections, self.config.solver, self._last_spp)
        if res.spp.ok:
            self._last_spp = res.spp.position
        return res

    def process(
        self,
        t: GpsTime,
        epoch: ObsEpoch | None,
        corrections: DgnssCorrections | None = None,
        uwb: Iterable[UwbRange] = (),
        front: EpochResult | None = None,
    ) -> NodeMessage:
        """The node message for nominal epoch `t`; `epoch` None means the receiver had no epoch.

        `front` is this epoch's `front_end` result when it was computed ahead; else it runs here.
        """
        if epoch is None:
            epoch = ObsEpoch(t, ())
        if self.first_epoch is None:
            self.first_epoch = t
        last = self._last_fused[1] if self._last_fused is not None else None
        res = front if front is not None else self.front_end(t, epoch, corrections)
        approx = res.spp.position if res.spp.ok else last
        sats = self._satellites(res, approx, corrections)
        plane = self._plane(t, approx) if self.method.planes != "none" else None
        msg = NodeMessage(
            fleet=self.fleet,
            vehicle_id=self.vehicle_id,
            seq=self.seq,
            epoch=epoch_time(t),
            rx_time=epoch_time(epoch.time),
            antenna_height_m=self.antenna_height_m,
            spp=self._spp_report(res),
            velocity=self._velocity_report(res),
            satellites=sats,
            plane=plane,
            ranges=[
                RangeReport(to=r.b, range_m=r.range_m, sigma_m=self.config.uwb_sigma_m)
                for r in uwb
                if r.a == self.vehicle_id and r.b != self.vehicle_id
            ],
        )
        self.seq += 1
        return msg

    def _spp_report(self, res: EpochResult) -> SppReport:
        s = res.spp
        if not s.ok:
            return SppReport(ok=False, reason=s.reason, excluded=list(s.excluded))
        d = s.dops
        return SppReport(
            ok=True,
            position_ecef_m=_tuple3(s.position),
            covariance_m2=_cov9(s.covariance),
            clocks_m=dict(s.clocks_m),
            n_used=s.n_used,
            excluded=list(s.excluded),
            gdop=d.gdop if d else None,
            pdop=d.pdop if d else None,
            hdop=d.hdop if d else None,
            vdop=d.vdop if d else None,
        )

    @staticmethod
    def _velocity_report(res: EpochResult) -> VelocityReport | None:
        v = res.velocity
        if v is None or not v.ok or np.linalg.norm(v.velocity_mps) > 150.0:
            return None
        sig = float(math.sqrt(max(np.trace(v.covariance) / 3.0, 1e-6)))
        return VelocityReport(
            velocity_ecef_mps=_tuple3(v.velocity_mps),
            sigma_mps=min(sig, 100.0),
            clock_drift_mps=v.drift_mps,
            n_used=len(v.used),
        )

    def _satellites(
        self, res: EpochResult, approx: Vec | None, corrections: DgnssCorrections | None
    ) -> list[SatelliteReport]:
        """Per-satellite factor inputs, modelled at the best position the vehicle has."""
        if approx is None:
            return []  # no position at all yet: elevation, Sagnac and atmosphere are unknown
        sats = list(res.prepared.sats)
        if corrections is not None:  # DGNSS mode uses corrected satellites only
            sats = [m for m in sats if m.sat in corrections.corrections_m]
        if not sats:
            return []
        systems = [m.system for m in sats]
        sat_pos = np.array([m.state.pos for m in sats])
        view = sky_view(sat_pos, approx)
        sat_rx = view.receive_frame_positions(sat_pos)
        cn0 = np.array([m.cn0_dbhz for m in sats])
        if corrections is not None:
            iono = tropo = np.zeros(len(sats))
            sigma = pseudorange_sigma_m(view.el_rad, cn0, systems)
        else:
            iono, tropo = broadcast_delays(systems, res.prepared.time, view, self.nav)
            sigma = standalone_pseudorange_sigma_m(view.el_rad, cn0, systems, iono)
        used = set(res.spp.used) if res.spp.ok else None
        excluded = set(res.spp.excluded)
        mask = math.radians(self.config.solver.spp.elevation_mask_deg)
        out: list[SatelliteReport] = []
        for i, m in enumerate(sats):
            el = float(view.el_rad[i])
            if corrections is not None:
                dg: float | None = corrections.corrections_m[m.sat]
                rho = m.pseudorange_m - corrections.corrections_m[m.sat]
            else:
                dg = None
                rho = m.pseudorange_m - m.tgd_m - float(iono[i]) - float(tropo[i])
            reason = None
            if m.sat in excluded:
                reason = "excluded by RAIM"
            elif el < mask:
                reason = "below elevation mask"
            elif used is not None and m.sat not in used:
                reason = "not used by SPP"
            out.append(
                SatelliteReport(
                    sat=m.sat,
                    pseudorange_m=m.pseudorange_m,
                    doppler_hz=m.doppler_hz if math.isfinite(m.doppler_hz) else None,
                    cn0_dbhz=m.cn0_dbhz if math.isfinite(m.cn0_dbhz) else None,
                    elevation_deg=math.degrees(el),
                    azimuth_deg=math.degrees(float(view.az_rad[i])),
                    sat_pos_ecef_m=_tuple3(sat_rx[i]),
                    sat_clock_s=m.state.clock_s,
                    tgd_m=m.tgd_m,
                    iono_m=float(iono[i]),
                    tropo_m=float(tropo[i]),
                    dgnss_m=dg,
                    rho_m=rho,
                    sigma_m=float(sigma[i]),
                    used=reason is None,
                    excluded_reason=reason,
                )
            )
        return out

    def _plane(self, t: GpsTime, centre: Vec | None) -> PlaneReport:
        if centre is None:
            return PlaneReport(status="unavailable", reason="no position to centre the fitting region")
        rng = np.random.default_rng(stable_seed(self.config.seed, self.vehicle_id, round(t.seconds * 1000)))
        only = {self.vehicle_id} if self.method.planes == "self" else None
        sample = self.history.select_records(centre, t.seconds, rng, vehicle_ids=only)
        plane = construct_plane(sample.points, self.antenna_height_m, self.plane_config, rng)
        return plane_report(plane, offset_sigma_m(sample.sigmas_up_m, sample.vehicle_ids))


def _sigma_up(v: VehicleState) -> float:
    """Vertical 1-sigma of a solved position (from its ECEF covariance), NaN when not given."""
    if v.covariance_m2 is None:
        return math.nan
    up = up_vector(np.asarray(v.position_ecef_m))
    var = float(up @ np.asarray(v.covariance_m2).reshape(3, 3) @ up)
    return math.sqrt(var) if var > 0 else math.nan


def plane_report(p: RoadPlane, offset_sigma: float = 0.0) -> PlaneReport:
    """The wire form of a plane; the factor's sigma adds the offset uncertainty to the fit residual."""
    if p.status == PlaneStatus.UNAVAILABLE:
        return PlaneReport(
            status="unavailable",
            reason=p.reason,
            n_points_initial=p.n_points_initial,
            n_points_used=p.n_points_used,
            residual_max_m=p.residual_max_m if math.isfinite(p.residual_max_m) else None,
        )
    return PlaneReport(
        status=_STATUS_NAME[p.status],  # type: ignore[arg-type]
        reason=p.reason,
        normal=_tuple3(p.normal),
        d_antenna_m=float(p.d_antenna),
        d_road_m=float(p.d_road),
        sigma_m=float(math.hypot(p.sigma_m, offset_sigma)),
        offset_sigma_m=float(offset_sigma),
        residual_max_m=float(p.residual_max_m),
        residual_rms_m=float(p.residual_rms_m),
        n_points_initial=p.n_points_initial,
        n_points_used=p.n_points_used,
        centroid_ecef_m=_tuple3(p.centroid),
    )


def plane_summary(p: PlaneReport | None) -> PlaneSummary | None:
    if p is None:
        return None
    return PlaneSummary(
        status=p.status,
        reason=p.reason,
        residual_max_m=p.residual_max_m,
        residual_rms_m=p.residual_rms_m,
        sigma_m=p.sigma_m,
        offset_sigma_m=p.offset_sigma_m,
        n_points_initial=p.n_points_initial,
        n_points_used=p.n_points_used,
    )


@dataclass
class FusionStepConfig:
    interruption_rate: float = 0.0  # paper 5.3: share of ranges removed per pair (seeded)
    interruption_seed: int = 0
    interval_s: float = 1.0  # the epoch index for interruption comes from time, not a counter


class FusionStep:
    """The server's epoch: node messages -> factor-graph inputs -> solution message (pure)."""

    def __init__(self, fleet: str, method: MethodSpec, config: FusionStepConfig | None = None) -> None:
        self.fleet = fleet
        self.method = method
        self.config = config or FusionStepConfig()
        self.estimator = method.build_estimator()
        self.seq = 0

    def inputs(self, t: GpsTime, messages: Mapping[str, NodeMessage]) -> EpochInput:
        vehicles: dict[str, VehicleEpochInput] = {}
        for vid in sorted(messages):
            vehicles[vid] = self._vehicle_input(t, messages[vid])
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
        return EpochInput(t, vehicles, tuple(ranges[k] for k in sorted(ranges)))

    def _vehicle_input(self, t: GpsTime, m: NodeMessage) -> VehicleEpochInput:
        prs = tuple(
            PseudorangeObs(
                sat=s.sat,
                rho_m=s.rho_m,
                sat_pos_m=np.array(s.sat_pos_ecef_m),
                sat_clock_s=s.sat_clock_s,
                sigma_m=s.sigma_m,
                elevation_rad=math.radians(s.elevation_deg),
                cn0_dbhz=s.cn0_dbhz if s.cn0_dbhz is not None else math.nan,
            )
            for s in m.satellites
            if s.used
        )
        vel = None
        if m.velocity is not None:
            vel = VelocityObs(np.array(m.velocity.velocity_ecef_mps), self.method.velocity_sigma_mps)
        plane = None
        if m.plane is not None and m.plane.status != "unavailable":
            assert (
                m.plane.normal is not None and m.plane.d_antenna_m is not None and m.plane.sigma_m is not None
            )
            plane = PlaneObs(np.array(m.plane.normal), m.plane.d_antenna_m, m.plane.sigma_m, m.plane.status)
        return VehicleEpochInput(
            vehicle_id=m.vehicle_id,
            time=t,
            pseudoranges=prs,
            velocity=vel,
            plane=plane,
            spp_position=np.array(m.spp.position_ecef_m) if m.spp.position_ecef_m is not None else None,
            clock_drift_mps=m.velocity.clock_drift_mps if m.velocity is not None else None,
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
                    position_ecef_m=_tuple3(est.position_m),
                    covariance_m2=_cov9(est.covariance_m2),
                    clocks_s=dict(est.clocks_s),
                    antenna_height_m=msg.antenna_height_m,
                    n_pseudoranges=est.n_pseudoranges,
                    n_ranges=est.n_ranges,
                    plane_used=est.plane_used,
                    plane_status=msg.plane.status if msg.plane is not None else None,
                    plane=plane_summary(msg.plane),
                    has_gnss_fix=est.has_gnss_fix,
                    n_satellites=sum(1 for s in msg.satellites if s.used),
                    spp_ok=msg.spp.ok,
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
