"""The API's in-memory picture of one fleet, fed by bus messages, read by the HTTP endpoints.

Pure and synchronous: no I/O, no clock of its own (callers pass `now`), so unit tests drive it
with hand-made messages. Everything is bounded: vehicles (`max_vehicles`, ids validated), track
points per vehicle (`history_per_vehicle`), errors kept for CEP95 (`accuracy_window`); counters
are keyed by fixed slugs only. Solved epochs only move forward: a repeated epoch is a duplicate,
an older one means the replay restarted (the fusion server came back), and the fleet picture is
reset for it (the accuracy of other methods is kept).
"""

from __future__ import annotations

import bisect
import math
import re
from collections import Counter, deque
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from coplane import __version__
from coplane.geo import ecef_to_geodetic, enu_rotation
from coplane.gtime import GpsTime
from coplane.messages import (
    DiagnosticsMessage,
    EpochTime,
    PlaneSummary,
    SolutionMessage,
    VehicleCounters,
    VehicleState,
)

from .models import (
    AccuracyEntry,
    AccuracyReport,
    GeoJsonFeature,
    GeoJsonFeatureCollection,
    GeoJsonLineString,
    GeoJsonPoint,
    Health,
    Origin,
    PlaneCounts,
    PlaneEntry,
    PlaneList,
    Readiness,
    StreamEvent,
    StreamVehicle,
    Track,
    TrackPoint,
    VehicleDetail,
    VehicleList,
    VehicleSummary,
)

Vec3 = tuple[float, float, float]
Mat = NDArray[np.float64]
VEHICLE_ID = re.compile(r"^[A-Za-z0-9_-]{1,32}$")

SOLVE_TIME_BUCKETS = (0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0)
LATENCY_BUCKETS = (0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0)
MAX_LATENCY_S = 86_400.0  # beyond this a latency stamp is a clock problem, not a latency
MAX_METHODS = 16  # accuracy is kept per method; a flood of method names must not grow memory


def _v3(a: Iterable[float]) -> Vec3:
    x, y, z = (float(v) for v in a)
    return (x, y, z)


class Histogram:
    """Fixed buckets, Prometheus semantics (cumulative on export), constant memory."""

    def __init__(self, bounds: tuple[float, ...]) -> None:
        self.bounds = bounds
        self.counts = [0] * (len(bounds) + 1)  # last: +Inf
        self.sum = 0.0
        self.count = 0

    def observe(self, x: float) -> None:
        self.counts[bisect.bisect_left(self.bounds, x)] += 1
        self.sum += x
        self.count += 1

    def cumulative(self) -> list[tuple[str, float]]:
        out, acc = [], 0
        for b, c in zip((*map(repr, self.bounds), "+Inf"), self.counts, strict=True):
            acc += c
            out.append((b, float(acc)))
        return out


class RunningAccuracy:
    """H/V errors of one vehicle under one method: exact all-time sums, bounded CEP95 window."""

    def __init__(self, window: int) -> None:
        self.n = 0
        self.sum_h2 = 0.0
        self.sum_v2 = 0.0
        self.sum_h = 0.0
        self.sum_v = 0.0
        self.max_h = 0.0
        self.max_v = 0.0
        self.h: deque[float] = deque(maxlen=window)
        self.last_h: float | None = None

    def add(self, h: float, v: float) -> None:
        self.n += 1
        self.sum_h2 += h * h
        self.sum_v2 += v * v
        self.sum_h += h
        self.sum_v += v
        self.max_h = max(self.max_h, h)
        self.max_v = max(self.max_v, abs(v))
        self.h.append(h)
        self.last_h = h

    def entry(self, vehicle_id: str, method: str, n_truth: int) -> AccuracyEntry:
        n = self.n
        ok = n > 0
        return AccuracyEntry(
            vehicle_id=vehicle_id,
            method=method,
            n_truth=n_truth,
            n_solved=n,
            availability=n / n_truth if n_truth else 0.0,
            h_rmse_m=math.sqrt(self.sum_h2 / n) if ok else None,
            v_rmse_m=math.sqrt(self.sum_v2 / n) if ok else None,
            cep95_m=float(np.percentile(np.fromiter(self.h, float), 95)) if self.h else None,
            cep95_samples=len(self.h),
            h_max_m=self.max_h if ok else None,
            v_max_m=self.max_v if ok else None,
            h_mean_m=self.sum_h / n if ok else None,
            v_bias_m=self.sum_v / n if ok else None,
            last_error_h_m=self.last_h,
        )


class Truth:
    """Truth positions of one vehicle keyed by nominal epoch, with the ENU rotation at each point."""

    def __init__(self, points: Mapping[GpsTime, Iterable[float]]) -> None:
        self.points = {t: np.asarray(list(p), dtype=float) for t, p in points.items()}
        self.times = sorted(t.seconds for t in self.points)
        self._rot: dict[GpsTime, Mat] = {}

    def error(self, t: GpsTime, ecef: Vec3) -> tuple[float, float] | None:
        """(horizontal, signed vertical) error at epoch t, or None without truth there."""
        ref = self.points.get(t)
        if ref is None:
            return None
        rot = self._rot.get(t)
        if rot is None:
            lat, lon, _ = ecef_to_geodetic(ref)
            rot = self._rot[t] = enu_rotation(lat, lon)
        e = rot @ (np.asarray(ecef, dtype=float) - ref)
        return float(math.hypot(e[0], e[1])), float(e[2])

    def count_between(self, first_s: float, last_s: float) -> int:
        return bisect.bisect_right(self.times, last_s + 1e-6) - bisect.bisect_left(self.times, first_s - 1e-6)


@dataclass(slots=True)
class _Point:
    t: GpsTime
    ecef: Vec3
    llh: Vec3  # degrees, degrees, metres
    enu: Vec3
    cov: tuple[float, ...] | None
    plane_status: str | None
    error_h: float | None


@dataclass
class _Vehicle:
    vid: str
    track: deque[_Point]
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


class FleetState:
    """Latest states, bounded tracks, running accuracy, plane counts, liveliness and readiness."""

    def __init__(
        self,
        fleet: str,
        *,
        history_per_vehicle: int = 3600,
        max_vehicles: int = 1024,
        accuracy_window: int = 86_400,
        stale_after_s: float = 10.0,
        truth: Mapping[str, Mapping[GpsTime, Iterable[float]]] | None = None,
        known_vehicles: Iterable[str] = (),
        started: float = 0.0,
    ) -> None:
        self.fleet = fleet
        self.history = history_per_vehicle
        self.max_vehicles = max_vehicles
        self.accuracy_window = accuracy_window
        self.stale_after_s = stale_after_s
        self.started = started
        self.truth = {v: Truth(p) for v, p in (truth or {}).items() if p}
        self.vehicles: dict[str, _Vehicle] = {}
        for v in known_vehicles:
            self._vehicle(v)
        self.fusion_alive: set[str] = set()
        self.solutions = 0
        self.duplicates = 0
        self.rewinds = 0
        self.last_t: GpsTime | None = None
        self.last_method: str | None = None
        self.last_received: float | None = None
        self.origin: Origin | None = None
        self._origin_ecef: Mat | None = None
        self._origin_rot: Mat | None = None
        self.accuracy: dict[str, dict[str, RunningAccuracy]] = {}
        self.windows: dict[str, tuple[GpsTime, GpsTime]] = {}  # method -> (first, last) epoch seen
        self.diagnostics: DiagnosticsMessage | None = None
        self.rejected: Counter[tuple[str, str]] = Counter()  # (source, kind)
        self.solve_time = Histogram(SOLVE_TIME_BUCKETS)
        self.latency = Histogram(LATENCY_BUCKETS)

    # -- bookkeeping -------------------------------------------------------------------------
    def _vehicle(self, vid: str) -> _Vehicle | None:
        """The entry of `vid`, created if there is room and the id is well-formed."""
        v = self.vehicles.get(vid)
        if v is not None:
            return v
        if not VEHICLE_ID.match(vid):
            self.rejected["vehicle", "bad-vehicle-id"] += 1
            return None
        if len(self.vehicles) >= self.max_vehicles:
            self.rejected["vehicle", "too-many-vehicles"] += 1
            return None
        v = self.vehicles[vid] = _Vehicle(vid, deque(maxlen=self.history))
        return v

    def reject(self, source: str, kind: str) -> None:
        """Count a bus payload that was not used (source: solution | diagnostics | liveliness | bus)."""
        self.rejected[source, kind] += 1

    def _set_origin(self, ecef: Vec3) -> None:
        lat, lon, h = ecef_to_geodetic(ecef)
        self._origin_ecef = np.asarray(ecef, dtype=float)
        self._origin_rot = enu_rotation(lat, lon)
        self.origin = Origin(
            ecef_m=ecef, lat_deg=math.degrees(lat), lon_deg=math.degrees(lon), height_m=float(h)
        )

    def _enu(self, ecef: Vec3) -> Vec3:
        assert self._origin_rot is not None and self._origin_ecef is not None
        return _v3(self._origin_rot @ (np.asarray(ecef, dtype=float) - self._origin_ecef))

    def _rewind(self, method: str) -> None:
        """A replay restarted: forget tracks, states and this method's accuracy (others stay)."""
        self.rewinds += 1
        for v in self.vehicles.values():
            v.track.clear()
            v.state = v.method = v.seq = v.t = v.received = None
            v.llh = v.enu = v.cov_enu = v.error = None
            v.plane_counts.clear()
            v.plane_t = None
        self.accuracy.pop(method, None)
        self.windows.pop(method, None)
        self.origin = self._origin_ecef = self._origin_rot = None
        self.last_t = None

    # -- inputs ------------------------------------------------------------------------------
    def on_solution(self, sol: SolutionMessage, now: float) -> bool:
        """Take one fleet solution; False if it was not used (other fleet, duplicate epoch)."""
        if sol.fleet != self.fleet:
            self.reject("solution", "wrong-fleet")
            return False
        if sol.method not in self.accuracy and len(self.accuracy) >= MAX_METHODS:
            self.reject("solution", "too-many-methods")
            return False
        t = GpsTime(sol.epoch.week, sol.epoch.tow)
        if self.last_t is not None:
            if t == self.last_t:
                self.duplicates += 1
                return False
            if t < self.last_t:
                self._rewind(sol.method)
        self.last_t = t
        self.last_method = sol.method
        self.last_received = now
        self.solutions += 1
        self.solve_time.observe(sol.solve_time_s)
        if sol.oldest_node_sent_unix_s is not None:
            lat_s = now - sol.oldest_node_sent_unix_s
            if 0.0 <= lat_s < MAX_LATENCY_S:
                self.latency.observe(lat_s)
        first, _ = self.windows.get(sol.method, (t, t))
        self.windows[sol.method] = (first, t)
        acc = self.accuracy.setdefault(sol.method, {})
        for vs in sol.vehicles:
            v = self._vehicle(vs.vehicle_id)
            if v is None:
                continue
            if self.origin is None:
                self._set_origin(vs.position_ecef_m)
            self._take_state(v, vs, sol, t, now, acc)
        return True

    def _take_state(
        self,
        v: _Vehicle,
        vs: VehicleState,
        sol: SolutionMessage,
        t: GpsTime,
        now: float,
        acc: dict[str, RunningAccuracy],
    ) -> None:
        lat, lon, h = ecef_to_geodetic(vs.position_ecef_m)
        llh = (math.degrees(lat), math.degrees(lon), float(h))
        enu = self._enu(vs.position_ecef_m)
        cov_enu = None
        if vs.covariance_m2 is not None:
            rot = enu_rotation(lat, lon)
            cov_enu = rot @ np.asarray(vs.covariance_m2, dtype=float).reshape(3, 3) @ rot.T
        truth = self.truth.get(v.vid)
        err = truth.error(t, vs.position_ecef_m) if truth is not None else None
        if err is not None:
            acc.setdefault(v.vid, RunningAccuracy(self.accuracy_window)).add(*err)
        v.state, v.method, v.seq, v.t, v.received = vs, sol.method, sol.seq, t, now
        v.llh, v.enu, v.cov_enu, v.error = llh, enu, cov_enu, err
        v.plane_counts[vs.plane_status or "none"] += 1
        v.plane_t = t
        cov = tuple(vs.covariance_m2) if vs.covariance_m2 is not None else None
        v.track.append(_Point(t, vs.position_ecef_m, llh, enu, cov, vs.plane_status, err[0] if err else None))

    def on_diagnostics(self, d: DiagnosticsMessage) -> bool:
        if d.fleet != self.fleet:
            self.reject("diagnostics", "wrong-fleet")
            return False
        self.diagnostics = d
        for vid, c in d.vehicles.items():
            v = self._vehicle(vid)
            if v is not None:
                v.counters = c
                v.server_online = c.online
        return True

    def on_alive(self, role: str, ident: str, present: bool) -> None:
        """A liveliness token appeared (present) or went away (role: agent | fusion | api)."""
        if role == "fusion":
            if not VEHICLE_ID.match(ident):
                self.reject("liveliness", "bad-id")
            elif present:
                if len(self.fusion_alive) < 64:
                    self.fusion_alive.add(ident)
            else:
                self.fusion_alive.discard(ident)
        elif role == "agent":
            v = self.vehicles.get(ident) if not present else self._vehicle(ident)
            if v is not None:
                v.online = present

    def bus_lost(self) -> None:
        """The router went away: every token we saw through it is gone too."""
        self.fusion_alive.clear()
        for v in self.vehicles.values():
            v.online = False

    # -- outputs -----------------------------------------------------------------------------
    def _summary_fields(self, v: _Vehicle, now: float) -> dict[str, object]:
        s = v.state
        out: dict[str, object] = {
            "vehicle_id": v.vid,
            "online": v.online,
            "server_online": v.server_online,
        }
        if s is None or v.t is None or v.llh is None:
            return out
        sig_h = sig_v = None
        if v.cov_enu is not None:
            sig_h = math.sqrt(max(0.0, v.cov_enu[0, 0] + v.cov_enu[1, 1]))
            sig_v = math.sqrt(max(0.0, v.cov_enu[2, 2]))
        out.update(
            method=v.method,
            seq=v.seq,
            epoch=EpochTime(week=v.t.week, tow=v.t.tow),
            gps_s=v.t.seconds,
            position_ecef_m=s.position_ecef_m,
            lat_deg=v.llh[0],
            lon_deg=v.llh[1],
            height_m=v.llh[2],
            enu_m=v.enu,
            sigma_h_m=sig_h,
            sigma_v_m=sig_v,
            has_gnss_fix=s.has_gnss_fix,
            spp_ok=s.spp_ok,
            plane_status=s.plane_status,
            plane_used=s.plane_used,
            n_satellites=s.n_satellites,
            n_pseudoranges=s.n_pseudoranges,
            n_ranges=s.n_ranges,
            error_h_m=v.error[0] if v.error else None,
            error_v_m=v.error[1] if v.error else None,
            age_s=max(0.0, now - v.received) if v.received is not None else None,
        )
        return out

    def vehicle_list(self, now: float) -> VehicleList:
        return VehicleList(
            fleet=self.fleet,
            method=self.last_method,
            epoch=EpochTime(week=self.last_t.week, tow=self.last_t.tow) if self.last_t else None,
            origin=self.origin,
            vehicles=[
                VehicleSummary.model_validate(self._summary_fields(v, now))
                for _, v in sorted(self.vehicles.items())
            ],
        )

    def vehicle_detail(self, vid: str, now: float) -> VehicleDetail | None:
        v = self.vehicles.get(vid)
        if v is None:
            return None
        f = self._summary_fields(v, now)
        s = v.state
        if s is not None:
            f.update(
                covariance_m2=list(s.covariance_m2) if s.covariance_m2 is not None else None,
                covariance_enu_m2=[float(x) for x in v.cov_enu.ravel()] if v.cov_enu is not None else None,
                clocks_s=dict(s.clocks_s),
                antenna_height_m=s.antenna_height_m,
                plane=s.plane,
            )
        f.update(counters=v.counters, track_points=len(v.track))
        return VehicleDetail.model_validate(f)

    def _points(self, vid: str, since: float | None, limit: int | None) -> list[_Point] | None:
        v = self.vehicles.get(vid)
        if v is None:
            return None
        pts = list(v.track)
        if since is not None:
            pts = [p for p in pts if p.t.seconds > since]
        if limit is not None:
            pts = pts[-limit:] if limit > 0 else []
        return pts

    def track(self, vid: str, since: float | None = None, limit: int | None = None) -> Track | None:
        pts = self._points(vid, since, limit)
        if pts is None:
            return None
        return Track(
            vehicle_id=vid,
            fleet=self.fleet,
            since=since,
            capacity=self.history,
            points=[
                TrackPoint(
                    week=p.t.week,
                    tow=p.t.tow,
                    gps_s=p.t.seconds,
                    position_ecef_m=p.ecef,
                    lat_deg=p.llh[0],
                    lon_deg=p.llh[1],
                    height_m=p.llh[2],
                    enu_m=p.enu,
                    covariance_m2=list(p.cov) if p.cov is not None else None,
                    plane_status=p.plane_status,  # type: ignore[arg-type]
                    error_h_m=p.error_h,
                )
                for p in pts
            ],
        )

    def track_geojson(
        self, vid: str, since: float | None = None, limit: int | None = None
    ) -> GeoJsonFeatureCollection | None:
        """RFC 7946: [lon, lat, height]; a LineString from two points on, a Point for one."""
        pts = self._points(vid, since, limit)
        if pts is None:
            return None
        coords = [[p.llh[1], p.llh[0], p.llh[2]] for p in pts]
        props: dict[str, object] = {
            "vehicle_id": vid,
            "fleet": self.fleet,
            "gps_s": [p.t.seconds for p in pts],
        }
        feats: list[GeoJsonFeature] = []
        if len(coords) >= 2:
            feats.append(GeoJsonFeature(geometry=GeoJsonLineString(coordinates=coords), properties=props))
        elif coords:
            feats.append(GeoJsonFeature(geometry=GeoJsonPoint(coordinates=coords[0]), properties=props))
        return GeoJsonFeatureCollection(features=feats)

    @staticmethod
    def _counts(c: Counter[str]) -> PlaneCounts:
        return PlaneCounts(
            available=c["available"],
            available_after_fe=c["available-after-fe"],
            unavailable=c["unavailable"],
            none=c["none"],
        )

    @staticmethod
    def _ratio(c: Counter[str]) -> float | None:
        with_plane = c["available"] + c["available-after-fe"] + c["unavailable"]
        return (c["available"] + c["available-after-fe"]) / with_plane if with_plane else None

    def plane_ratio(self, vid: str) -> float | None:
        v = self.vehicles.get(vid)
        return self._ratio(v.plane_counts) if v is not None else None

    def planes(self) -> PlaneList:
        entries, now, total = [], Counter[str](), Counter[str]()
        for vid, v in sorted(self.vehicles.items()):
            s = v.state
            p: PlaneSummary | None = s.plane if s is not None else None
            if s is not None:
                now[s.plane_status or "none"] += 1
            total.update(v.plane_counts)
            entries.append(
                PlaneEntry(
                    vehicle_id=vid,
                    epoch=EpochTime(week=v.plane_t.week, tow=v.plane_t.tow) if v.plane_t else None,
                    status=s.plane_status if s is not None else None,
                    reason=p.reason if p is not None else None,
                    plane_used=s.plane_used if s is not None else None,
                    residual_max_m=p.residual_max_m if p is not None else None,
                    residual_rms_m=p.residual_rms_m if p is not None else None,
                    sigma_m=p.sigma_m if p is not None else None,
                    n_points_initial=p.n_points_initial if p is not None else 0,
                    n_points_used=p.n_points_used if p is not None else 0,
                    counts=self._counts(v.plane_counts),
                    availability_ratio=self._ratio(v.plane_counts),
                )
            )
        return PlaneList(
            fleet=self.fleet, now=self._counts(now), availability_ratio=self._ratio(total), vehicles=entries
        )

    def accuracy_report(self) -> AccuracyReport:
        entries = []
        for method, per in sorted(self.accuracy.items()):
            first, last = self.windows[method]
            for vid, ra in sorted(per.items()):
                n_truth = self.truth[vid].count_between(first.seconds, last.seconds)
                entries.append(ra.entry(vid, method, n_truth))
        return AccuracyReport(fleet=self.fleet, truth_vehicles=sorted(self.truth), entries=entries)

    def live_agents(self) -> int:
        return sum(1 for v in self.vehicles.values() if v.online)

    def readiness(self, now: float, bus_connected: bool) -> Readiness:
        """Ready: bus up, a fusion server alive, a solution seen, and solutions flowing if agents are live."""
        reasons = []
        age = now - self.last_received if self.last_received is not None else None
        live = self.live_agents()
        if not bus_connected:
            reasons.append("not connected to a Zenoh router")
        if not self.fusion_alive:
            reasons.append("no fusion server liveliness token (alive/fusion/*)")
        if self.solutions == 0:
            reasons.append("no solution received yet")
        elif age is not None and age > self.stale_after_s and live > 0:
            reasons.append(f"no solution for {age:.1f} s while {live} agent(s) are live")
        return Readiness(
            ready=not reasons,
            bus_connected=bus_connected,
            fusion_alive=bool(self.fusion_alive),
            solutions_received=self.solutions,
            last_solution_age_s=age,
            live_agents=live,
            reasons=reasons,
        )

    def health(self, now: float) -> Health:
        return Health(version=__version__, uptime_s=max(0.0, now - self.started))

    def stream_event(self, sol: SolutionMessage, now: float) -> StreamEvent | None:
        """The compact /stream event of a solution just taken (None if it was not taken)."""
        if self.origin is None:
            return None
        t = GpsTime(sol.epoch.week, sol.epoch.tow)
        out = []
        for vs in sol.vehicles:
            v = self.vehicles.get(vs.vehicle_id)
            if v is None or v.t != t or v.enu is None or v.llh is None:
                continue  # not taken (no room for another vehicle)
            sig_h = math.sqrt(max(0.0, v.cov_enu[0, 0] + v.cov_enu[1, 1])) if v.cov_enu is not None else None
            out.append(
                StreamVehicle(
                    vehicle_id=v.vid,
                    enu_m=v.enu,
                    lat_deg=v.llh[0],
                    lon_deg=v.llh[1],
                    sigma_h_m=sig_h,
                    plane_status=vs.plane_status,
                    plane_used=vs.plane_used,
                    has_gnss_fix=vs.has_gnss_fix,
                    error_h_m=v.error[0] if v.error else None,
                    online=v.online,
                )
            )
        lat_s = now - sol.oldest_node_sent_unix_s if sol.oldest_node_sent_unix_s is not None else None
        return StreamEvent(
            fleet=sol.fleet,
            method=sol.method,
            seq=sol.seq,
            epoch=sol.epoch,
            gps_s=t.seconds,
            solve_time_s=sol.solve_time_s,
            latency_s=lat_s if lat_s is not None and 0.0 <= lat_s < MAX_LATENCY_S else None,
            origin=self.origin,
            vehicles=out,
        )
