"""The API's in-memory store of one fleet and its ingestion of bus messages.

Pure and synchronous: no I/O, no clock of its own (callers pass `now`), so unit tests drive it
with hand-made messages; `views` turns it into the served models. Everything is bounded: vehicles
(`max_vehicles`, ids validated), track points per vehicle (`history_per_vehicle`), errors kept for
CEP95 (`accuracy_window`); counters are keyed by fixed slugs only. Every solution passes the
consumers' `SolutionGate` first (`coplane.bus.trust`): solved epochs only move forward within a
server generation (a repeated epoch is a duplicate, an older one stale), implausible positions and
epochs are rejected, and the fleet picture is reset only when a new server generation takes over
(see docs/api.md, "Which solutions the API takes").
"""

from __future__ import annotations

import bisect
import math
from collections import Counter, deque
from collections.abc import Iterable, Mapping

import numpy as np

from coplane.bus.gates import MAX_SERVERS, GateSet
from coplane.bus.trust import Verdict
from coplane.geo import ecef_to_geodetic, enu_rotation
from coplane.gtime import GpsTime
from coplane.ids import is_vehicle_id
from coplane.messages import (
    DiagnosticsMessage,
    SolutionMessage,
    VehicleState,
    merge_diagnostics,
)
from coplane.regions import RegionConfig
from coplane.typing import Mat

from .accuracy import RunningAccuracy, TruthTrack
from .models import Origin, StreamEvent, StreamVehicle
from .records import StoredVehicle, Vec3, stored_point

SOLVE_TIME_BUCKETS = (0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0)
LATENCY_BUCKETS = (0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0)
MAX_LATENCY_S = 86_400.0  # beyond this a latency stamp is a clock problem, not a latency
MAX_METHODS = 16  # accuracy is kept per method; a flood of method names must not grow memory


def _v3(a: Iterable[float]) -> Vec3:
    x, y, z = (float(v) for v in a)
    return (x, y, z)


def horizontal_sigma_m(cov_enu: Mat | None) -> float | None:
    """Horizontal 1-sigma (metres) of an ENU covariance: sqrt(var_e + var_n)."""
    return math.sqrt(max(0.0, cov_enu[0, 0] + cov_enu[1, 1])) if cov_enu is not None else None


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


class FleetState:
    """Latest states, bounded tracks, running accuracy, plane counts, liveliness and counters."""

    def __init__(
        self,
        fleet: str,
        *,
        history_per_vehicle: int = 3600,
        max_vehicles: int = 256,
        accuracy_window: int = 86_400,
        stale_after_s: float = 10.0,
        truth: Mapping[str, Mapping[GpsTime, Iterable[float]]] | None = None,
        known_vehicles: Iterable[str] = (),
        started: float = 0.0,
        gate: GateSet | None = None,
        regions: RegionConfig | None = None,
    ) -> None:
        self.fleet = fleet
        self.history = history_per_vehicle
        self.max_vehicles = max_vehicles
        self.accuracy_window = accuracy_window
        self.stale_after_s = stale_after_s
        self.started = started
        self.truth = {v: TruthTrack(p) for v, p in (truth or {}).items() if p}
        self.vehicles: dict[str, StoredVehicle] = {}
        known = list(known_vehicles)
        for v in known:
            self._vehicle(v)
        # with a recording the fleet's vehicles are known: no other id is taken from a solution
        # one gate per fusion server: with regions each server is its own run (docs/scale.md)
        # `regions`: several servers share the fleet, each speaking only of its regions' vehicles
        self.gate = gate or GateSet(fleet, regions=regions, vehicles=known or None, max_vehicles=max_vehicles)
        self.last_verdict: Verdict | None = None  # of the latest solution offered (for the ingest's log)
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
        self.diagnostics: DiagnosticsMessage | None = None  # the server's, or all servers' merged
        self.server_diagnostics: dict[str, DiagnosticsMessage] = {}  # by server ("": the single one)
        self.rejected: Counter[tuple[str, str]] = Counter()  # (source, kind)
        self.solve_time = Histogram(SOLVE_TIME_BUCKETS)
        self.latency = Histogram(LATENCY_BUCKETS)

    # -- bookkeeping -------------------------------------------------------------------------
    def _vehicle(self, vid: str) -> StoredVehicle | None:
        """The entry of `vid`, created if there is room and the id is well-formed."""
        v = self.vehicles.get(vid)
        if v is not None:
            return v
        if not is_vehicle_id(vid):
            self.rejected["vehicle", "bad-vehicle-id"] += 1
            return None
        if len(self.vehicles) >= self.max_vehicles:
            self.rejected["vehicle", "too-many-vehicles"] += 1
            return None
        v = self.vehicles[vid] = StoredVehicle(vid, deque(maxlen=self.history))
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
        """A new server generation took over (the gate said so): forget tracks, states and this
        method's accuracy (others stay)."""
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
    def on_solution(self, sol: SolutionMessage, now: float, server: str = "") -> bool:
        """Take one fleet solution if the gate lets it through; False if it was not used (the reason
        is counted: `duplicates` for a repeated epoch, `rejected["solution", reason]` otherwise,
        `rejected["vehicle", reason]` for vehicles left out of a taken one)."""
        self.last_verdict = None
        if sol.method not in self.accuracy and len(self.accuracy) >= MAX_METHODS:
            self.reject("solution", "too-many-methods")
            return False
        verdict = self.last_verdict = self.gate.check(server, sol, now)
        if verdict.solution is None:
            if verdict.reason == "repeat":
                self.duplicates += 1
            else:
                self.reject("solution", verdict.reason or "untrusted")
            return False
        for _, reason in verdict.dropped:
            self.reject("vehicle", reason)
        if verdict.reset and not server:
            self._rewind(sol.method)  # with regions a server's restart is a take-over: tracks go on
        sol = verdict.solution
        t = GpsTime(sol.epoch.week, sol.epoch.tow)
        self.last_t = t if self.last_t is None or self.last_t < t or not server else self.last_t
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
            if server and v.t is not None and t <= v.t:
                self.reject("vehicle", "older-than-held")  # two servers during a hand-over
                continue
            self._take_state(v, vs, sol, t, now, acc)
        return True

    def _take_state(
        self,
        v: StoredVehicle,
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
        v.track.append(stored_point(vs, t, llh, enu, err))

    def on_diagnostics(self, d: DiagnosticsMessage, server: str = "") -> bool:
        """Take the server's counters; False for another fleet, or for another server generation
        than the one whose solutions the gate follows (a stray or forged server's counters)."""
        if d.fleet != self.fleet:
            self.reject("diagnostics", "wrong-fleet")
            return False
        g = self.gate.gates.get(server)
        gen = g.generation if g is not None else None
        if d.generation is not None and gen is not None and d.generation != gen:
            self.reject("diagnostics", "other-generation")
            return False
        if server not in self.server_diagnostics and len(self.server_diagnostics) >= MAX_SERVERS:
            self.reject("diagnostics", "too-many-servers")
            return False
        self.server_diagnostics[server] = d
        if len(self.server_diagnostics) > 1:
            d = merge_diagnostics(list(self.server_diagnostics.values()))
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
            if not is_vehicle_id(ident):
                self.reject("liveliness", "bad-id")
                return
            if present:
                if len(self.fusion_alive) < 64:
                    self.fusion_alive.add(ident)
            else:
                self.fusion_alive.discard(ident)
            # a server that withdrew its token ended its run: its successor is followed at once
            self.gate.server_token(ident, present)
        elif role == "agent":
            v = self.vehicles.get(ident) if not present else self._vehicle(ident)
            if v is not None:
                v.online = present

    def bus_lost(self) -> None:
        """The router went away: every token we saw through it is gone too (the servers' are
        announced again on reconnect; that is no server's departure, so no run ends here)."""
        self.fusion_alive.clear()
        self.gate.servers_alive.clear()
        for v in self.vehicles.values():
            v.online = False

    def stream_event(self, sol: SolutionMessage, now: float) -> StreamEvent | None:
        """The compact /stream event of a solution just taken (None if it was not taken).

        Part of ingestion, not of `views`: the ingest path publishes it right after `on_solution`,
        from the entries that call just wrote.
        """
        if self.origin is None:
            return None
        t = GpsTime(sol.epoch.week, sol.epoch.tow)
        out = []
        for vs in sol.vehicles:
            v = self.vehicles.get(vs.vehicle_id)
            if v is None or v.t != t or v.enu is None or v.llh is None:
                continue  # not taken (no room for another vehicle)
            out.append(
                StreamVehicle(
                    vehicle_id=v.vid,
                    enu_m=v.enu,
                    lat_deg=v.llh[0],
                    lon_deg=v.llh[1],
                    sigma_h_m=horizontal_sigma_m(v.cov_enu),
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
