"""Helpers for the API tests: hand-made fleet solutions with known truth, and an app served by
uvicorn in a thread (for the SSE client and the headless browser)."""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import uvicorn

from coplane.api.app import create_app
from coplane.api.bus_client import LocalBus
from coplane.api.settings import ApiSettings
from coplane.api.state import FleetState
from coplane.bus import encode
from coplane.fleet import free_port, wait_for_port
from coplane.geo import enu_to_ecef, geodetic_to_ecef
from coplane.gtime import GpsTime
from coplane.messages import (
    DiagnosticsMessage,
    EpochTime,
    PlaneSummary,
    SolutionMessage,
    VehicleCounters,
    VehicleState,
)

FLEET = "testfleet"
ORIGIN = geodetic_to_ecef(math.radians(35.0), math.radians(137.0), 50.0)
T0 = GpsTime(2320, 100000.0)
STATUSES = ("available", "available-after-fe", "unavailable", None)


def ecef_at(e: float, n: float, u: float = 0.0) -> tuple[float, float, float]:
    x, y, z = enu_to_ecef([e, n, u], ORIGIN)
    return (float(x), float(y), float(z))


def vehicle_state(
    vid: str,
    ecef: tuple[float, float, float],
    plane_status: str | None = "available",
    cov_diag: float = 0.25,
) -> VehicleState:
    plane = None
    if plane_status is not None:
        plane = PlaneSummary(
            status=plane_status,  # type: ignore[arg-type]
            reason=None if plane_status != "unavailable" else "too-few-points: 3 < 15",
            residual_max_m=0.2,
            residual_rms_m=0.1,
            sigma_m=0.3,
            n_points_initial=20,
            n_points_used=18,
            source="fleet",
        )
    return VehicleState(
        vehicle_id=vid,
        position_ecef_m=ecef,
        covariance_m2=[cov_diag, 0, 0, 0, cov_diag, 0, 0, 0, cov_diag],
        clocks_s={"G": 1e-4},
        antenna_height_m=1.5,
        n_pseudoranges=9,
        n_ranges=2,
        plane_used=plane_status in ("available", "available-after-fe"),
        plane_status=plane_status,  # type: ignore[arg-type]
        plane=plane,
        has_gnss_fix=True,
        n_satellites=10,
        spp_ok=True,
        hdop=0.9,
        vdop=1.6,
    )


def solution(
    seq: int,
    t: GpsTime,
    states: list[VehicleState],
    method: str = "pc",
    fleet: str = FLEET,
    sent: float | None = None,
) -> SolutionMessage:
    return SolutionMessage(
        fleet=fleet,
        method=method,
        seq=seq,
        epoch=EpochTime(week=t.week, tow=t.tow),
        vehicles=states,
        solve_time_s=0.004 + 0.001 * (seq % 5),
        oldest_node_sent_unix_s=sent,
    )


@dataclass
class SyntheticFleet:
    """Vehicles driving east on parallel lanes; each solution is truth plus a known ENU error."""

    n_vehicles: int = 4
    n_epochs: int = 60
    truth: dict[str, dict[GpsTime, tuple[float, float, float]]] = field(default_factory=dict)
    errors: dict[str, dict[GpsTime, tuple[float, float, float]]] = field(default_factory=dict)

    @property
    def ids(self) -> list[str]:
        return [f"v{i + 1}" for i in range(self.n_vehicles)]

    def truth_enu(self, i: int, k: int) -> tuple[float, float, float]:
        return (8.0 * k + 40.0 * i, 15.0 * i + 3.0 * math.sin(k / 9.0), 0.02 * k)

    def error_enu(self, i: int, k: int) -> tuple[float, float, float]:
        rng = np.random.default_rng(1000 * i + k)
        e = rng.normal(0.0, 1.0 + i, 3)
        return (float(e[0]), float(e[1]), float(e[2]))

    def __post_init__(self) -> None:
        for i, vid in enumerate(self.ids):
            self.truth[vid] = {}
            self.errors[vid] = {}
            for k in range(self.n_epochs):
                t = T0 + float(k)
                self.truth[vid][t] = ecef_at(*self.truth_enu(i, k))
                self.errors[vid][t] = self.error_enu(i, k)

    def solution(self, k: int, sent: float | None = None) -> SolutionMessage:
        t = T0 + float(k)
        states = []
        for i, vid in enumerate(self.ids):
            te, tn, tu = self.truth_enu(i, k)
            ee, en, eu = self.errors[vid][t]
            status = STATUSES[(i + k // 7) % len(STATUSES)]
            states.append(vehicle_state(vid, ecef_at(te + ee, tn + en, tu + eu), status, 0.2 + 0.1 * i))
        return solution(k, t, states, sent=sent)

    def diagnostics(self, k: int) -> DiagnosticsMessage:
        return DiagnosticsMessage(
            fleet=FLEET,
            method="pc",
            pace="lockstep",
            epochs_solved=k + 1,
            vehicles={
                vid: VehicleCounters(received=k + 3, used=k + 1, rejected=1, late=1, online=True)
                for vid in self.ids
            },
            rejected_by_reason={"invalid-json": len(self.ids)},
            live_vehicles=self.ids,
            cluster_workers=3,
            cluster_workers_lost=1,
            map_common_offset_m=0.25,
            map_common_passes=80,
            map_counts={"samples": 40, "passes_added": 6, "skipped:sigma-up": 3},
        )

    def state(self, history: int = 3600, window: int = 86_400, clock_now: float = 0.0) -> FleetState:
        return FleetState(
            FLEET,
            history_per_vehicle=history,
            accuracy_window=window,
            stale_after_s=3600.0,  # apps built at collection time must stay ready however long tests run
            truth=self.truth,
            known_vehicles=self.ids,
            started=clock_now,
        )


def filled_app(  # type: ignore[no-untyped-def]
    fleet: SyntheticFleet,
    epochs: int | None = None,
    bus: LocalBus | None = None,
    map_path: Path | None = None,
):
    """An app whose state already holds `epochs` solutions, diagnostics and liveliness."""
    st = fleet.state(clock_now=time.time())
    now = time.time()
    sol = None
    for k in range(fleet.n_epochs if epochs is None else epochs):
        sol = fleet.solution(k, sent=now - 0.01)
        st.on_solution(sol, now)
    st.on_diagnostics(fleet.diagnostics(fleet.n_epochs))
    st.on_alive("fusion", "0", True)
    for vid in fleet.ids[:-1]:
        st.on_alive("agent", vid, True)
    app = create_app(
        ApiSettings(fleet=FLEET, map=str(map_path) if map_path else None), bus or LocalBus(), state=st
    )
    ev = st.stream_event(sol, now) if sol is not None else None
    if ev is not None:
        app.state.hub.publish(ev)  # as Ingest would have: a new /stream client gets it first
    return app


@contextmanager
def serve(app, port: int | None = None) -> Iterator[str]:  # type: ignore[no-untyped-def]
    """Run `app` with uvicorn in a thread; yields its base URL and stops it afterwards."""
    port = port or free_port()
    cfg = uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning", timeout_graceful_shutdown=2)
    server = uvicorn.Server(cfg)
    th = threading.Thread(target=server.run, daemon=True)
    th.start()
    try:
        wait_for_port(port, 15.0)
        yield f"http://127.0.0.1:{port}"
    finally:
        app.state.hub.close()  # end open streams, else uvicorn waits for them
        server.should_exit = True
        th.join(10)


def feed(app, fleet: SyntheticFleet, start: int, stop: int, period_s: float) -> threading.Thread:  # type: ignore[no-untyped-def]
    """Publish solutions start..stop-1 through the app's Ingest from another thread, like Zenoh does."""
    ing = app.state.ingest

    def run() -> None:
        for k in range(start, stop):
            time.sleep(period_s)
            ing.submit(ing.solution, encode(fleet.solution(k, sent=time.time() - 0.02)))

    th = threading.Thread(target=run, daemon=True)
    th.start()
    return th
