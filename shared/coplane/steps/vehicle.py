"""`VehicleStep`: one vehicle's epoch, its measurements and the fleet's solution in, a node message out.

SPP + Doppler velocity (DGNSS when corrections are given), the road plane fitted from the fleet's
solved positions (paper Sec. III) and the per-satellite factor inputs, packed as the `NodeMessage`
the fusion step consumes. Pure and deterministic (no I/O): `coplane eval` calls it in-process and
the vehicle agent over the bus, so a lockstep replay over the bus reproduces the in-process
positions (docs/architecture.md).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np

from coplane.estimation.limits import MAX_SPEED_MPS
from coplane.geo import up_vector
from coplane.gnss.dgnss import DgnssCorrections
from coplane.gnss.epoch_solver import EpochResult, EpochSolverOptions, ReceiverMemory, solve_next
from coplane.gnss.geometry import broadcast_delays, sky_view
from coplane.gnss.weighting import pseudorange_sigma_m, standalone_pseudorange_sigma_m
from coplane.gtime import GpsTime
from coplane.messages import (
    NodeMessage,
    PlaneReport,
    PlaneSourceName,
    RangeReport,
    SatelliteColumns,
    SolutionMessage,
    SppReport,
    VehicleState,
    VelocityReport,
)
from coplane.methods import MethodSpec
from coplane.plane.config import PlaneConfig
from coplane.plane.detect import construct_plane, offset_sigma_m
from coplane.plane.history import PositionHistory
from coplane.plane.uncertainty import plane_uncertainty
from coplane.recording.model import NavData, ObsEpoch, UwbRange
from coplane.steps.wire import (
    cov9,
    epoch_time,
    gps_time,
    map_plane_report,
    plane_report,
    stable_seed,
    tuple3,
)
from coplane.typing import AnyArray as Vec

if TYPE_CHECKING:
    from coplane.roadmap import RoadMap


@dataclass
class VehicleStepConfig:
    solver: EpochSolverOptions = field(default_factory=EpochSolverOptions)
    plane: PlaneConfig = field(default_factory=PlaneConfig)
    uwb_sigma_m: float = 0.3
    seed: int = 0
    road_map: RoadMap | None = None
    """The road-surface map a `plane_map` method takes its planes from (read here, never written:
    the map learns from the fusion server's solutions, docs/roadmap.md). The vehicle agent fills
    a map of the tiles around it from the bus; `coplane eval --map` passes a loaded one."""


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
        self.history_shared = False  # True: a SharedHistory feeds `history`, ingest leaves it alone
        self.road_map = self.config.road_map
        self.seq = 0
        self.first_epoch: GpsTime | None = None
        self._last_fused: tuple[GpsTime, Vec] | None = None
        self._receiver = ReceiverMemory()

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
        # no plane, no history to keep; a shared history is fed once by its SharedHistory
        if states and self.method.planes != "none" and not self.history_shared:
            store_states(self.history, t, states)
        for v in states:
            if v.vehicle_id == self.vehicle_id:
                self.note_fused(t, v.position_ecef_m)

    def share_history(self, history: PositionHistory) -> None:
        """Take its plane points from `history`, which a `SharedHistory` fills (not `ingest`)."""
        self.history = history
        self.history_shared = True

    def note_fused(self, t: GpsTime, position_ecef_m: Iterable[float]) -> None:
        """Keep this vehicle's own fused position of `t` (the plane's centre when SPP fails)."""
        self._last_fused = (t, np.asarray(position_ecef_m, dtype=float))

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
        return solve_next(ep, self.nav, self._receiver, corrections, self.config.solver)

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
        # modelled where SPP evaluated them (a decimetre at most from its fix), else at `approx`
        sats = self._satellites(res, res.spp.model_position if res.spp.ok else approx, corrections)
        plane = self._plane(t, approx) if self.method.planes != "none" else None
        msg = NodeMessage(
            fleet=self.fleet,
            vehicle_id=self.vehicle_id,
            seq=self.seq,
            epoch=epoch_time(t),
            rx_time=epoch_time(epoch.time),
            antenna_height_m=self.antenna_height_m,
            spp=self._spp_report(res, None if corrections is None else epoch.time - corrections.time),
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

    def _spp_report(self, res: EpochResult, dgnss_age_s: float | None) -> SppReport:
        """`dgnss_age_s`: how old the base corrections were (a live base lags; users see it)."""
        s = res.spp
        age = None if dgnss_age_s is None else round(min(max(dgnss_age_s, -60.0), 3600.0), 3)
        if not s.ok:
            return SppReport(ok=False, reason=s.reason, excluded=list(s.excluded), dgnss_age_s=age)
        d = s.dops
        return SppReport(
            ok=True,
            position_ecef_m=tuple3(s.position),
            covariance_m2=cov9(s.covariance),
            clocks_m=dict(s.clocks_m),
            n_used=s.n_used,
            excluded=list(s.excluded),
            gdop=d.gdop if d else None,
            pdop=d.pdop if d else None,
            hdop=d.hdop if d else None,
            vdop=d.vdop if d else None,
            dgnss_age_s=age,
        )

    @staticmethod
    def _velocity_report(res: EpochResult) -> VelocityReport | None:
        v = res.velocity
        if v is None or not v.ok or np.linalg.norm(v.velocity_mps) > MAX_SPEED_MPS:
            return None
        sig = float(math.sqrt(max(np.trace(v.covariance) / 3.0, 1e-6)))
        return VelocityReport(
            velocity_ecef_mps=tuple3(v.velocity_mps),
            sigma_mps=min(sig, 100.0),
            clock_drift_mps=v.drift_mps,
            n_used=len(v.used),
            few_satellites=v.few_satellites,
            standstill=v.standstill,
        )

    def _satellites(
        self, res: EpochResult, approx: Vec | None, corrections: DgnssCorrections | None
    ) -> SatelliteColumns:
        """Per-satellite factor inputs, modelled at the best position the vehicle has, as the
        wire's columns (validated once for the epoch)."""
        if approx is None:
            return SatelliteColumns()  # no position yet: elevation, Sagnac and atmosphere unknown
        prepared = res.prepared
        # the whole epoch's view and delays at `approx`: at SPP's, the ones it ended with (cached)
        view = sky_view(prepared.sat_pos, approx)
        if corrections is not None:  # DGNSS mode uses corrected satellites only
            sel = np.array([m.sat in corrections.corrections_m for m in prepared.sats], dtype=bool)
        else:
            sel = np.ones(len(prepared.sats), dtype=bool)
        sats = [m for m, k in zip(prepared.sats, sel.tolist(), strict=True) if k]
        if not sats:
            return SatelliteColumns()
        systems = [m.system for m in sats]
        el_rad, az_rad = view.el_rad[sel], view.az_rad[sel]
        sat_rx = view.receive_frame_positions(prepared.sat_pos)[sel]
        cn0 = np.array([m.cn0_dbhz for m in sats])
        if corrections is not None:
            iono = tropo = np.zeros(len(sats))
            sigma = pseudorange_sigma_m(el_rad, cn0, systems)
        else:
            iono, tropo = (d[sel] for d in broadcast_delays(prepared.systems, prepared.time, view, self.nav))
            sigma = standalone_pseudorange_sigma_m(el_rad, cn0, systems, iono)
        used = set(res.spp.used) if res.spp.ok else None
        excluded = set(res.spp.excluded)
        mask = math.radians(self.config.solver.spp.elevation_mask_deg)
        out: list[dict[str, object]] = []
        # Python floats up front, rather than indexing numpy arrays per satellite and field
        rows = zip(
            sats,
            el_rad.tolist(),
            az_rad.tolist(),
            sat_rx.tolist(),
            iono.tolist(),
            tropo.tolist(),
            sigma.tolist(),
            strict=True,
        )
        for m, el, az, pos_rx, iono_i, tropo_i, sigma_i in rows:
            if corrections is not None:
                dg: float | None = corrections.corrections_m[m.sat]
                rho = m.pseudorange_m - corrections.corrections_m[m.sat]
            else:
                dg = None
                rho = m.pseudorange_m - m.tgd_m - iono_i - tropo_i
            reason = None
            if m.sat in excluded:
                reason = "excluded by RAIM"
            elif el < mask:
                # never used: near the horizon the mapping functions blow up (Saastamoinen gives
                # ~100 m at 1 deg, ~1 km at 0.1 deg), so no atmospheric model is applied or reported
                reason = "below elevation mask"
                iono_i = tropo_i = 0.0
                if corrections is None:
                    rho = m.pseudorange_m - m.tgd_m
            elif used is not None and m.sat not in used:
                reason = "not used by SPP"
            out.append(
                dict(
                    sat=m.sat,
                    pseudorange_m=m.pseudorange_m,
                    doppler_hz=m.doppler_hz if math.isfinite(m.doppler_hz) else None,
                    cn0_dbhz=m.cn0_dbhz if math.isfinite(m.cn0_dbhz) else None,
                    elevation_deg=math.degrees(el),
                    azimuth_deg=math.degrees(az),
                    sat_pos_ecef_m=tuple(pos_rx),
                    sat_clock_s=m.state.clock_s,
                    tgd_m=m.tgd_m,
                    iono_m=iono_i,
                    tropo_m=tropo_i,
                    dgnss_m=dg,
                    rho_m=rho,
                    sigma_m=sigma_i,
                    used=reason is None,
                    excluded_reason=reason,
                )
            )
        return SatelliteColumns.from_rows(out)  # one validation for the epoch's columns

    def _plane(self, t: GpsTime, centre: Vec | None) -> PlaneReport:
        if centre is None:
            return PlaneReport(status="unavailable", reason="no position to centre the fitting region")
        fitted = self._fitted_plane(t, centre)
        if self.method.plane_map and self.road_map is not None:
            mapped = self.road_map.plane_at(centre, self.antenna_height_m)
            if mapped is not None:
                return more_certain_plane(map_plane_report(mapped), fitted)
        return fitted

    def _fitted_plane(self, t: GpsTime, centre: Vec) -> PlaneReport:
        """The paper's plane: fitted from the history's points around `centre` (Sec. III)."""
        source: PlaneSourceName = "self" if self.method.planes == "self" else "fleet"
        rng = np.random.default_rng(stable_seed(self.config.seed, self.vehicle_id, round(t.seconds * 1000)))
        only = {self.vehicle_id} if self.method.planes == "self" else None
        since = self.first_epoch.seconds if self.first_epoch is not None else -math.inf
        sample = self.history.select_records(centre, t.seconds, rng, vehicle_ids=only, since_time_s=since)
        cfg = self.plane_config
        plane = construct_plane(sample.points, self.antenna_height_m, cfg, rng)
        if cfg.sigma_model == "covariance" and plane.available:
            # the plane's covariance propagated to where this vehicle is (the fitting centre)
            u = plane_uncertainty(plane, sample.sigmas_up_m, sample.vehicle_ids, sample.times_s, cfg)
            return plane_report(plane, u.offset_sigma_m, u.sigma_at(centre), u.tilt_sigma_rad, source)
        return plane_report(plane, offset_sigma_m(sample.sigmas_up_m, sample.vehicle_ids), source=source)


def more_certain_plane(mapped: PlaneReport, fitted: PlaneReport) -> PlaneReport:
    """The map's plane unless the history's fit is more certain at the vehicle (smaller sigma).

    A tile made from one drive carries that drive's height errors (sigma ~0.7 m, docs/results.md
    "Road-surface map"), where a plane fitted from this minute's fleet may know the road better; a
    tile sharpened by many passes wins. The two are not combined: both come from the same fleet's
    positions on the same road, so their errors are not independent."""
    if fitted.status == "unavailable" or fitted.sigma_m is None or mapped.sigma_m is None:
        return mapped
    return fitted if fitted.sigma_m < mapped.sigma_m else mapped


def store_states(history: PositionHistory, t: GpsTime, states: Sequence[VehicleState]) -> None:
    """Put solved vehicle states of epoch `t` into a plane history (paper eq. 2)."""
    history.add_many(
        [v.vehicle_id for v in states],
        t.seconds,
        [v.position_ecef_m for v in states],
        [v.antenna_height_m for v in states],
        [vertical_sigma_m(v) for v in states],
    )


def vertical_sigma_m(v: VehicleState) -> float:
    """Vertical 1-sigma of a solved position (from its ECEF covariance), NaN when not given."""
    if v.covariance_m2 is None:
        return math.nan
    up = up_vector(np.asarray(v.position_ecef_m))
    var = float(up @ np.asarray(v.covariance_m2).reshape(3, 3) @ up)
    return math.sqrt(var) if var > 0 else math.nan
