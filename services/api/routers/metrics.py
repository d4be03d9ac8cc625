"""Prometheus metrics: a custom collector that reads the fleet state at scrape time.

Message counts are the fusion server's own totals (from its diagnostics), exposed as counters:
the server is the one place that sees every node message, and re-exporting its totals keeps
counter semantics (a server restart is an ordinary counter reset for `rate()`). Histograms of
solve time and epoch latency are built here from the solutions the API received. One registry per
app (not the global one), so several apps in one process (tests) do not collide.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator

from fastapi import APIRouter
from fastapi.responses import Response
from prometheus_client import CONTENT_TYPE_LATEST, CollectorRegistry, ProcessCollector, generate_latest
from prometheus_client.core import (
    CounterMetricFamily,
    GaugeMetricFamily,
    HistogramMetricFamily,
    Metric,
)
from prometheus_client.registry import Collector

from .. import views
from ..bus_client import Bus, Ingest
from ..deps import RegistryDep
from ..hub import StreamHub
from ..state import FleetState

router = APIRouter(tags=["metrics"])

# (metric suffix, VehicleCounters field, help)
PER_VEHICLE = (
    ("messages_received", "received", "Node messages the fusion server received from the vehicle"),
    ("messages_used", "used", "Node messages used in a solve"),
    ("messages_rejected", "rejected", "Node messages rejected as invalid"),
    ("messages_late", "late", "Node messages that arrived after their epoch was solved"),
    ("messages_duplicate", "duplicate", "Duplicate node messages (resends)"),
    ("messages_out_of_order", "out_of_order", "Node messages older than the vehicle's latest"),
    ("epochs_missing", "missing", "Epochs solved while the live vehicle had not reported"),
)


class FleetCollector(Collector):
    def __init__(
        self, state: FleetState, ingest: Ingest, hub: StreamHub, bus: Bus, clock: Callable[[], float]
    ) -> None:
        self.state = state
        self.ingest = ingest
        self.hub = hub
        self.bus = bus
        self.clock = clock

    def collect(self) -> Iterator[Metric]:
        st = self.state
        d = st.diagnostics
        for suffix, attr, doc in PER_VEHICLE:
            c = CounterMetricFamily(f"coplane_{suffix}", doc + " (fusion server totals)", labels=["vehicle"])
            if d is not None:
                for vid, vc in sorted(d.vehicles.items()):
                    if vid in st.vehicles:  # bounded and validated ids only (label cardinality)
                        c.add_metric([vid], float(getattr(vc, attr)))
            yield c
        r = CounterMetricFamily(
            "coplane_messages_rejected_by_reason",
            "Node messages rejected by the fusion server, by reason (includes unknown vehicles)",
            labels=["reason"],
        )
        if d is not None:
            for reason, n in sorted(d.rejected_by_reason.items()):
                r.add_metric([reason], float(n))
        yield r
        solved = CounterMetricFamily("coplane_epochs_solved", "Epochs the fusion server solved")
        if d is not None:
            solved.add_metric([], float(d.epochs_solved))
        yield solved
        live = GaugeMetricFamily(
            "coplane_live_vehicles", "Vehicles the fusion server counts as live (its last diagnostics)"
        )
        live.add_metric([], float(len(d.live_vehicles)) if d is not None else 0.0)
        yield live
        online = GaugeMetricFamily(
            "coplane_vehicle_online",
            "1 while the vehicle's agent liveliness token is present",
            labels=["vehicle"],
        )
        ratio = GaugeMetricFamily(
            "coplane_plane_availability_ratio",
            "Share of epochs with a usable plane (available or after FE) among epochs with a plane report",
            labels=["vehicle"],
        )
        dgnss = GaugeMetricFamily(
            "coplane_vehicle_dgnss_age_seconds",
            "Age of the base corrections in the vehicle's latest state (absent: no DGNSS)",
            labels=["vehicle"],
        )
        for vid in sorted(st.vehicles):
            vehicle = st.vehicles[vid]
            online.add_metric([vid], 1.0 if vehicle.online else 0.0)
            pr = views.plane_ratio(st, vid)
            if pr is not None:
                ratio.add_metric([vid], pr)
            if vehicle.state is not None and vehicle.state.dgnss_age_s is not None:
                dgnss.add_metric([vid], vehicle.state.dgnss_age_s)
        yield online
        yield ratio
        yield dgnss
        fleet_ratio = views.planes(st).availability_ratio
        fr = GaugeMetricFamily(
            "coplane_fleet_plane_availability_ratio", "Plane availability over all vehicles"
        )
        if fleet_ratio is not None:
            fr.add_metric([], fleet_ratio)
        yield fr
        for name, h, doc in (
            ("coplane_solve_time_seconds", st.solve_time, "Fusion solve time per epoch (from solutions)"),
            (
                "coplane_epoch_latency_seconds",
                st.latency,
                "Solution arrival at the API minus the publish time of the epoch's oldest node message",
            ),
        ):
            yield HistogramMetricFamily(name, doc, buckets=h.cumulative(), sum_value=h.sum)
        fus = GaugeMetricFamily("coplane_fusion_servers_alive", "Fusion server liveliness tokens present")
        fus.add_metric([], float(len(st.fusion_alive)))
        yield fus
        workers = GaugeMetricFamily(
            "coplane_fusion_cluster_workers",
            "Processes solving a fusion server's clusters (--cluster_workers), running or lost, from its diagnostics",
            labels=["server", "state"],
        )
        for server, d in sorted(st.server_diagnostics.items()):
            workers.add_metric([server, "running"], float(d.cluster_workers - d.cluster_workers_lost))
            workers.add_metric([server, "lost"], float(d.cluster_workers_lost))
        yield workers
        offset = GaugeMetricFamily(
            "coplane_map_common_offset_metres",
            "Median height of recent passes against the road map, every usable tile (+: fleet above the map)",
            labels=["server"],
        )
        for server, d in sorted(st.server_diagnostics.items()):
            if d.map_common_offset_m is not None:
                offset.add_metric([server], d.map_common_offset_m)
        yield offset
        evidence = CounterMetricFamily(
            "coplane_map_evidence",
            "What became of the fleet's road-map evidence, per server (samples, passes_added,"
            " skipped:<reason> of the trust filter, e.g. skipped:sigma-up for a standalone fleet)",
            labels=["server", "kind"],
        )
        for server, d in sorted(st.server_diagnostics.items()):
            for kind, n in sorted(d.map_counts.items()):
                evidence.add_metric([server, kind], float(n))
        yield evidence
        sol = CounterMetricFamily("coplane_api_solutions", "Solutions the API took into its state")
        sol.add_metric([], float(st.solutions))
        yield sol
        dup = CounterMetricFamily("coplane_api_duplicate_solutions", "Solutions for an epoch already seen")
        dup.add_metric([], float(st.duplicates))
        yield dup
        rw = CounterMetricFamily(
            "coplane_api_replay_restarts", "A new fusion server generation took over: state was reset"
        )
        rw.add_metric([], float(st.rewinds))
        yield rw
        rej = CounterMetricFamily(
            "coplane_api_rejected",
            "Bus payloads the API could not use, by source and kind (source=solution: the"
            " SolutionGate's reasons, e.g. off-earth, stale, too-far-ahead, new-generation;"
            " source=vehicle: vehicles left out of a taken solution)",
            labels=["source", "kind"],
        )
        for (source, kind), n in sorted(st.rejected.items()):
            rej.add_metric([source, kind], float(n))
        yield rej
        drop = CounterMetricFamily(
            "coplane_api_dropped",
            "Items dropped to stay bounded (bus: decode backlog full; stream: slow client)",
            labels=["where"],
        )
        drop.add_metric(["bus"], float(self.ingest.dropped))
        drop.add_metric(["stream"], float(self.hub.dropped))
        yield drop
        clients = GaugeMetricFamily("coplane_api_stream_clients", "Connected /stream clients")
        clients.add_metric([], float(len(self.hub.clients)))
        yield clients
        now = self.clock()
        ready = GaugeMetricFamily("coplane_api_ready", "1 when /readyz would answer 200")
        ready.add_metric([], 1.0 if views.readiness(st, now, self.bus.connected()).ready else 0.0)
        yield ready
        age = GaugeMetricFamily(
            "coplane_api_last_solution_age_seconds", "Wall seconds since the last solution"
        )
        if st.last_received is not None:
            age.add_metric([], max(0.0, now - st.last_received))
        yield age


def make_registry(collector: FleetCollector) -> CollectorRegistry:
    reg = CollectorRegistry(auto_describe=False)
    reg.register(collector)
    ProcessCollector(registry=reg)  # process_* (memory, CPU, open fds) of the API itself
    return reg


@router.get(
    "/metrics",
    response_class=Response,
    responses={
        200: {
            "description": "Prometheus text exposition format 0.0.4",
            "content": {"text/plain": {"schema": {"type": "string"}}},
        }
    },
    summary="Prometheus metrics",
)
async def metrics(registry: RegistryDep) -> Response:
    return Response(generate_latest(registry), media_type=CONTENT_TYPE_LATEST)
