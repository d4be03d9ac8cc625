"""Views of the fleet store: the models every endpoint serves, built from `FleetState`.

Read-only functions of the store and the caller's `now`, so each endpoint's JSON is one call
and the store stays free of presentation (docs/api.md lists the endpoints and their models).
"""

from __future__ import annotations

import datetime as dt
import math
from collections import Counter

from coplane import __version__
from coplane.gtime import gpst_to_utc
from coplane.messages import EpochTime, PlaneSummary, plane_source

from .models import (
    AccuracyReport,
    GeoJsonFeature,
    GeoJsonFeatureCollection,
    GeoJsonLineString,
    GeoJsonPoint,
    Health,
    PlaneCounts,
    PlaneEntry,
    PlaneList,
    Readiness,
    Track,
    TrackPoint,
    VehicleDetail,
    VehicleList,
    VehicleSummary,
)
from .records import StoredPoint, StoredVehicle
from .state import FleetState, horizontal_sigma_m


def _summary_fields(v: StoredVehicle, now: float) -> dict[str, object]:
    """The fields VehicleSummary and VehicleDetail share; state fields only once a solution was taken."""
    s = v.state
    out: dict[str, object] = {
        "vehicle_id": v.vid,
        "online": v.online,
        "server_online": v.server_online,
    }
    if s is None or v.t is None or v.llh is None:
        return out
    sig_v = math.sqrt(max(0.0, v.cov_enu[2, 2])) if v.cov_enu is not None else None
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
        sigma_h_m=horizontal_sigma_m(v.cov_enu),
        sigma_v_m=sig_v,
        has_gnss_fix=s.has_gnss_fix,
        spp_ok=s.spp_ok,
        plane_status=s.plane_status,
        plane_used=s.plane_used,
        plane_source=plane_source(s.plane),
        n_satellites=s.n_satellites,
        n_pseudoranges=s.n_pseudoranges,
        excluded_satellites=list(s.excluded_satellites),
        raim_excluded=list(s.raim_excluded),
        hdop=s.hdop,
        vdop=s.vdop,
        n_ranges=s.n_ranges,
        dgnss_age_s=s.dgnss_age_s,
        error_h_m=v.error[0] if v.error else None,
        error_v_m=v.error[1] if v.error else None,
        age_s=max(0.0, now - v.received) if v.received is not None else None,
    )
    return out


def vehicle_list(st: FleetState, now: float) -> VehicleList:
    return VehicleList(
        fleet=st.fleet,
        method=st.last_method,
        epoch=EpochTime(week=st.last_t.week, tow=st.last_t.tow) if st.last_t else None,
        origin=st.origin,
        vehicles=[
            VehicleSummary.model_validate(_summary_fields(v, now)) for _, v in sorted(st.vehicles.items())
        ],
    )


def vehicle_detail(st: FleetState, vid: str, now: float) -> VehicleDetail | None:
    v = st.vehicles.get(vid)
    if v is None:
        return None
    f = _summary_fields(v, now)
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


def _points(st: FleetState, vid: str, since: float | None, limit: int | None) -> list[StoredPoint] | None:
    """The held points of `vid` after `since`, the last `limit` of them; None for an unknown id."""
    v = st.vehicles.get(vid)
    if v is None:
        return None
    pts = list(v.track)
    if since is not None:
        pts = [p for p in pts if p.t.seconds > since]
    if limit is not None:
        pts = pts[-limit:] if limit > 0 else []
    return pts


def track(st: FleetState, vid: str, since: float | None = None, limit: int | None = None) -> Track | None:
    pts = _points(st, vid, since, limit)
    if pts is None:
        return None
    return Track(
        vehicle_id=vid,
        fleet=st.fleet,
        since=since,
        capacity=st.history,
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
                error_v_m=p.error_v,
                n_satellites=p.n_satellites,
                n_pseudoranges=p.n_pseudoranges,
                excluded_satellites=list(p.excluded),
                raim_excluded=list(p.raim_excluded),
                vdop=p.vdop,
                has_gnss_fix=p.gnss_fix,
                dgnss_age_s=p.dgnss_age,
                n_ranges=p.n_ranges,
                plane_used=p.plane_used,
                plane_source=p.plane_source,
                hdop=p.hdop,
            )
            for p in pts
        ],
    )


def track_geojson(
    st: FleetState, vid: str, since: float | None = None, limit: int | None = None
) -> GeoJsonFeatureCollection | None:
    """RFC 7946: [lon, lat, height]; a LineString from two points on, a Point for one."""
    pts = _points(st, vid, since, limit)
    if pts is None:
        return None
    coords = [[p.llh[1], p.llh[0], p.llh[2]] for p in pts]
    props: dict[str, object] = {
        "vehicle_id": vid,
        "fleet": st.fleet,
        "gps_s": [p.t.seconds for p in pts],
    }
    feats: list[GeoJsonFeature] = []
    if len(coords) >= 2:
        feats.append(GeoJsonFeature(geometry=GeoJsonLineString(coordinates=coords), properties=props))
    elif coords:
        feats.append(GeoJsonFeature(geometry=GeoJsonPoint(coordinates=coords[0]), properties=props))
    return GeoJsonFeatureCollection(features=feats)


def track_gpx(st: FleetState, vid: str, since: float | None = None, limit: int | None = None) -> str | None:
    """GPX 1.1 (gpxpy): one track of one segment, UTC times, ellipsoidal heights as elevation (GPX
    has no datum field; coplane has no geoid model, so the height is said in the track's comment)."""
    import gpxpy.gpx

    pts = _points(st, vid, since, limit)
    if pts is None:
        return None
    gpx = gpxpy.gpx.GPX()
    gpx.creator = "coplane"
    trk = gpxpy.gpx.GPXTrack(name=f"{st.fleet}/{vid}")
    trk.comment = "elevation: WGS-84 ellipsoidal height (m)"
    seg = gpxpy.gpx.GPXTrackSegment()
    for p in pts:
        when = gpst_to_utc(p.t).replace(tzinfo=dt.UTC)
        seg.points.append(gpxpy.gpx.GPXTrackPoint(p.llh[0], p.llh[1], elevation=p.llh[2], time=when))
    trk.segments.append(seg)
    gpx.tracks.append(trk)
    return gpx.to_xml(version="1.1")


def track_pos(st: FleetState, vid: str, since: float | None = None, limit: int | None = None) -> str | None:
    """RTKLIB's .pos layout, the rows `coplane eval --format pos` writes (`fused_pos_record`), for
    RTKPLOT."""
    from coplane.evaluate.solution_files import fused_pos_record, pos_text  # only when a track is asked for

    pts = _points(st, vid, since, limit)
    if pts is None:
        return None
    records = [fused_pos_record(p.t, p.ecef, p.cov, p.gnss_fix, p.dgnss_age, p.n_pseudoranges) for p in pts]
    return pos_text(records, mode=f"coplane {st.fleet}/{vid} (the API's track)")


def _counts(c: Counter[str]) -> PlaneCounts:
    """Plane statuses counted over epochs ("none": the vehicle sent no plane)."""
    return PlaneCounts(
        available=c["available"],
        available_after_fe=c["available-after-fe"],
        unavailable=c["unavailable"],
        none=c["none"],
    )


def _ratio(c: Counter[str]) -> float | None:
    """(available + after FE) / epochs with a plane report; None before the first report."""
    with_plane = c["available"] + c["available-after-fe"] + c["unavailable"]
    return (c["available"] + c["available-after-fe"]) / with_plane if with_plane else None


def plane_ratio(st: FleetState, vid: str) -> float | None:
    """The plane availability ratio of one vehicle (a Prometheus gauge)."""
    v = st.vehicles.get(vid)
    return _ratio(v.plane_counts) if v is not None else None


def planes(st: FleetState) -> PlaneList:
    entries, now, total = [], Counter[str](), Counter[str]()
    for vid, v in sorted(st.vehicles.items()):
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
                counts=_counts(v.plane_counts),
                availability_ratio=_ratio(v.plane_counts),
            )
        )
    return PlaneList(fleet=st.fleet, now=_counts(now), availability_ratio=_ratio(total), vehicles=entries)


def accuracy_report(st: FleetState) -> AccuracyReport:
    """Per method and vehicle; availability counts truth epochs within the method's epoch window."""
    entries = []
    for method, per in sorted(st.accuracy.items()):
        first, last = st.windows[method]
        for vid, ra in sorted(per.items()):
            n_truth = st.truth[vid].count_between(first.seconds, last.seconds)
            entries.append(ra.entry(vid, method, n_truth))
    return AccuracyReport(fleet=st.fleet, truth_vehicles=sorted(st.truth), entries=entries)


def live_agents(st: FleetState) -> int:
    return sum(1 for v in st.vehicles.values() if v.online)


def readiness(st: FleetState, now: float, bus_connected: bool) -> Readiness:
    """Ready: bus up, a fusion server alive, a solution seen, and solutions flowing if agents are live."""
    reasons = []
    age = now - st.last_received if st.last_received is not None else None
    live = live_agents(st)
    if not bus_connected:
        reasons.append("not connected to a Zenoh router")
    if not st.fusion_alive:
        reasons.append("no fusion server liveliness token (alive/fusion/*)")
    if st.solutions == 0:
        reasons.append("no solution received yet")
    elif age is not None and age > st.stale_after_s and live > 0:
        reasons.append(f"no solution for {age:.1f} s while {live} agent(s) are live")
    return Readiness(
        ready=not reasons,
        bus_connected=bus_connected,
        fusion_alive=bool(st.fusion_alive),
        solutions_received=st.solutions,
        last_solution_age_s=age,
        live_agents=live,
        reasons=reasons,
    )


def health(st: FleetState, now: float) -> Health:
    return Health(version=__version__, uptime_s=max(0.0, now - st.started))
