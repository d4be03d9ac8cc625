"""Direct tests of `coplane.steps`: VehicleStep, FusionStep and the wire conversions between them.

The vehicle side runs on the first epochs of the bundled recording (4 vehicles, DGNSS, UWB), in
lockstep as `coplane eval` does: every vehicle builds its node message, the fusion step solves the
epoch, every vehicle ingests the solution. FusionStep's own logic (which measurements reach the
estimator, how its estimates are wrapped) is tested with a recording stand-in estimator, so the
checks do not depend on the factor graph.
"""

from __future__ import annotations

import itertools
import math
import zlib
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pytest

from coplane.estimation.contract import EpochInput, FleetSolution, PseudorangeColumns, VehicleEstimate
from coplane.estimation.limits import MAX_SPEED_MPS
from coplane.geo import enu_to_ecef
from coplane.gnss.dgnss import DgnssCorrections
from coplane.gtime import GpsTime
from coplane.messages import (
    EpochTime,
    NodeMessage,
    PlaneReport,
    RangeReport,
    SatelliteColumns,
    SolutionMessage,
    VehicleState,
)
from coplane.methods import MethodSpec, get_method, interrupt_range
from coplane.plane.config import PlaneConfig
from coplane.plane.detect import construct_plane
from coplane.recording.model import ObsEpoch, UwbRange
from coplane.recording.reader import Recording, open_recording
from coplane.replay import BaseCorrections, uwb_for_vehicle, vehicle_schedule
from coplane.sim.generate import bundled_default_path
from coplane.steps import (
    FusionStep,
    FusionStepConfig,
    VehicleStep,
    VehicleStepConfig,
    epoch_time,
    gps_time,
    plane_report,
    plane_summary,
)
from coplane.steps.wire import cov9, stable_seed, tuple3

FLEET = "test-fleet"
IDS = ("u1", "u2", "u3", "u4")
N_EPOCHS = 6  # u3's plane becomes available at epoch 4 (15 points within 50 m)
REASONS = {"excluded by RAIM", "below elevation mask", "not used by SPP"}


@dataclass
class Run:
    """What a short lockstep run produced, epoch by epoch."""

    rec: Recording
    times: list[GpsTime]
    epochs: dict[str, list[ObsEpoch | None]]
    corrections: list[DgnssCorrections | None]
    uwb: dict[str, dict[GpsTime, list[UwbRange]]]
    messages: list[dict[str, NodeMessage]] = field(default_factory=list)
    solutions: list[SolutionMessage] = field(default_factory=list)
    steps: dict[str, VehicleStep] = field(default_factory=dict)
    fusion: FusionStep | None = None


def _vehicle(rec: Recording, vid: str, method: str | MethodSpec, **cfg: Any) -> VehicleStep:
    spec = get_method(method) if isinstance(method, str) else method
    v = rec.manifest.vehicle(vid)
    return VehicleStep(FLEET, vid, v.antenna_height_m, rec.nav, spec, VehicleStepConfig(**cfg))


@pytest.fixture(scope="module")
def rec() -> Recording:
    return open_recording(bundled_default_path())


@pytest.fixture(scope="module")
def run(rec: Recording) -> Run:
    """N_EPOCHS lockstep epochs of method "pc" with DGNSS and UWB (about 3 s, once per module)."""
    dt = rec.interval_s
    sched = {vid: vehicle_schedule(rec.vehicle_epochs(vid), dt)[:N_EPOCHS] for vid in IDS}
    times = [t for t, _ in sched["u1"]]
    assert all([t for t, _ in sched[v]] == times for v in IDS)
    base = BaseCorrections.of(rec, use_dgnss=True)
    rows = rec.uwb()
    r = Run(
        rec,
        times,
        {vid: [e for _, e in sched[vid]] for vid in IDS},
        [base.at(t) for t in times],
        {vid: uwb_for_vehicle(rows, vid, times, dt) for vid in IDS},
    )
    r.steps = {vid: _vehicle(rec, vid, "pc") for vid in IDS}
    r.fusion = FusionStep(FLEET, get_method("pc"), FusionStepConfig(interval_s=dt))
    for k, t in enumerate(times):
        if r.solutions:
            for s in r.steps.values():
                s.ingest(r.solutions[-1])
        msgs = {
            vid: r.steps[vid].process(t, r.epochs[vid][k], r.corrections[k], r.uwb[vid].get(t, ()))
            for vid in IDS
        }
        r.messages.append(msgs)
        r.solutions.append(r.fusion.solve(t, msgs))
    return r


# -- VehicleStep: the node message --------------------------------------------------------------


def test_node_message_header(run: Run) -> None:
    """A node message names its fleet and vehicle, the nominal epoch and the receiver's exact tag."""
    m = run.messages[0]["u2"]
    ep = run.epochs["u2"][0]
    assert ep is not None
    assert (m.fleet, m.vehicle_id, m.seq) == (FLEET, "u2", 0)
    assert m.epoch == EpochTime(week=run.times[0].week, tow=run.times[0].tow)
    assert gps_time(m.rx_time) == ep.time != run.times[0]  # the receiver tags 4 ms after the second
    assert m.antenna_height_m == run.rec.manifest.vehicle("u2").antenna_height_m
    assert m.sent_unix_s is None  # only the agent stamps wall-clock time


def test_seq_and_epoch_advance(run: Run) -> None:
    """seq counts the vehicle's messages from 0 and each carries its nominal epoch."""
    for vid in IDS:
        assert [run.messages[k][vid].seq for k in range(N_EPOCHS)] == list(range(N_EPOCHS))
        assert [gps_time(run.messages[k][vid].epoch) for k in range(N_EPOCHS)] == run.times
        assert run.steps[vid].first_epoch == run.times[0]
        assert run.steps[vid].seq == N_EPOCHS


def test_spp_and_velocity_reports(run: Run) -> None:
    """A vehicle with enough satellites sends an SPP fix and a plausible Doppler velocity."""
    for vid in IDS:
        m = run.messages[2][vid]
        assert m.spp.ok and m.spp.position_ecef_m is not None and m.spp.n_used >= 4
        assert m.spp.covariance_m2 is not None and len(m.spp.covariance_m2) == 9
        assert m.velocity is not None
        assert 0 < m.velocity.sigma_mps <= 100.0
        assert np.linalg.norm(m.velocity.velocity_ecef_mps) <= MAX_SPEED_MPS
        assert m.velocity.n_used >= 5


def test_satellites_used_and_excluded_reasons(run: Run) -> None:
    """Each satellite is used or has exactly one known exclusion reason consistent with SPP and the mask."""
    seen: set[str] = set()
    for msgs in run.messages:
        for m in msgs.values():
            assert m.satellites, m.vehicle_id
            excluded = set(m.spp.excluded)
            for s in m.satellites.rows():
                assert s.used == (s.excluded_reason is None)
                if s.excluded_reason is not None:
                    assert s.excluded_reason in REASONS
                    seen.add(s.excluded_reason)
                if s.excluded_reason == "excluded by RAIM":
                    assert s.sat in excluded
                elif s.excluded_reason == "below elevation mask":
                    assert s.elevation_deg < 10.0 and s.sat not in excluded
                else:
                    assert s.sat not in excluded
                if s.used:
                    assert s.elevation_deg >= 10.0
            assert len(set(m.satellites.sat)) == len(m.satellites)
    assert {"excluded by RAIM", "below elevation mask"} <= seen  # the first epochs exercise both


def test_dgnss_satellites_carry_the_correction(run: Run) -> None:
    """With DGNSS, rho = pseudorange - correction and no model delays; only corrected satellites are sent."""
    for k, msgs in enumerate(run.messages):
        corr = run.corrections[k]
        assert corr is not None
        for m in msgs.values():
            for s in m.satellites.rows():
                assert s.dgnss_m == corr.corrections_m[s.sat]
                assert s.rho_m == s.pseudorange_m - s.dgnss_m
                assert s.iono_m == 0.0 and s.tropo_m == 0.0


def test_standalone_satellites_carry_the_models(rec: Recording) -> None:
    """Without corrections, rho = pseudorange - TGD - iono - tropo with broadcast model delays;
    satellites below the mask (never used) get no atmospheric model: near the horizon it blows up
    (Saastamoinen ~100 m at 1 deg, which the message rightly refuses)."""
    ep = rec.vehicle_epochs("u1")[0]
    m = _vehicle(rec, "u1", "non-cp").process(ep.time.round_to(1.0), ep)
    assert m.satellites
    for s in m.satellites.rows():
        assert s.dgnss_m is None
        assert s.rho_m == s.pseudorange_m - s.tgd_m - s.iono_m - s.tropo_m
        if s.excluded_reason == "below elevation mask":
            assert s.tropo_m == 0.0 and s.iono_m == 0.0 and not s.used
        else:
            assert s.tropo_m > 0.0 and s.iono_m != 0.0


def test_no_plane_for_methods_without_planes(rec: Recording) -> None:
    """Methods with planes "none" (non-cp, mci, the baselines) send no plane report at all."""
    ep = rec.vehicle_epochs("u1")[0]
    for method in ("non-cp", "mci", "non-cp-ekf"):
        assert get_method(method).planes == "none"
        m = _vehicle(rec, "u1", method).process(ep.time.round_to(1.0), ep)
        assert m.plane is None and m.satellites


def test_plane_report_for_pc(run: Run) -> None:
    """Method pc sends a plane report every epoch: unavailable with a reason first, then available for u3."""
    first = run.messages[0]["u1"].plane
    assert first is not None and first.status == "unavailable" and first.reason == "no fitting points"
    for msgs in run.messages:
        for m in msgs.values():
            assert m.plane is not None
    p = run.messages[N_EPOCHS - 1]["u3"].plane
    assert p is not None and p.status in ("available", "available-after-fe")
    assert p.normal is not None and abs(np.linalg.norm(p.normal) - 1.0) < 1e-9
    assert p.d_antenna_m is not None and p.d_road_m is not None and p.sigma_m is not None
    height = run.rec.manifest.vehicle("u3").antenna_height_m
    assert p.d_antenna_m == pytest.approx(p.d_road_m - height)
    assert p.offset_sigma_m is not None and p.sigma_m >= p.offset_sigma_m
    assert p.n_points_used >= PlaneConfig().n_min
    # the solution says the plane reached the estimator and was used for u3
    u3 = {v.vehicle_id: v for v in run.solutions[N_EPOCHS - 1].vehicles}["u3"]
    assert u3.plane_used and u3.plane_status == p.status and u3.plane is not None


def test_plane_points_grow_with_the_fleet_history(run: Run) -> None:
    """The plane's fitting points come from the ingested fleet solutions: none at first, more every epoch."""
    n = [run.messages[k]["u3"].plane.n_points_initial for k in range(N_EPOCHS)]  # type: ignore[union-attr]
    assert n[0] == 0 and n[1] > 0
    assert all(b >= a for a, b in itertools.pairwise(n))


def test_ranges_only_from_this_vehicle(rec: Recording) -> None:
    """UWB rows the vehicle measured become ranges with the configured sigma; others' and self rows are dropped."""
    ep = rec.vehicle_epochs("u1")[0]
    t = ep.time.round_to(1.0)
    rows = [UwbRange(t, "u1", "u2", 8.5), UwbRange(t, "u2", "u1", 8.6), UwbRange(t, "u1", "u1", 1.0)]
    m = _vehicle(rec, "u1", "mci", uwb_sigma_m=0.7).process(t, ep, uwb=rows)
    assert m.ranges == [RangeReport(to="u2", range_m=8.5, sigma_m=0.7)]


def test_missing_receiver_epoch(rec: Recording) -> None:
    """Without a receiver epoch and no earlier position: no fix, no satellites, an unavailable plane saying why."""
    t = rec.vehicle_epochs("u1")[0].time.round_to(1.0)
    m = _vehicle(rec, "u1", "pc").process(t, None)
    assert m.rx_time == m.epoch == epoch_time(t)
    assert not m.spp.ok and m.spp.reason
    assert m.velocity is None and len(m.satellites) == 0
    assert m.plane is not None and m.plane.status == "unavailable"
    assert m.plane.reason == "no position to centre the fitting region"


def test_front_end_ahead_gives_the_same_message(run: Run) -> None:
    """Running the GNSS front end ahead and passing it to process gives the identical message."""
    k, vid = 1, "u4"
    a, b = _vehicle(run.rec, vid, "pc"), _vehicle(run.rec, vid, "pc")
    for s in (a, b):
        s.process(run.times[0], run.epochs[vid][0], run.corrections[0])
        s.ingest(run.solutions[0])
    front = b.front_end(run.times[k], run.epochs[vid][k], run.corrections[k])
    ma = a.process(run.times[k], run.epochs[vid][k], run.corrections[k])
    mb = b.process(run.times[k], run.epochs[vid][k], run.corrections[k], front=front)
    assert ma == mb
    assert ma == run.messages[k][vid].model_copy(update={"ranges": []})


def test_vehicle_step_is_deterministic_and_wire_exact(run: Run) -> None:
    """A fresh step fed the same inputs sends the same message, and the message survives JSON unchanged."""
    vid = "u3"
    s = _vehicle(run.rec, vid, "pc")
    for k, t in enumerate(run.times):
        if k:
            s.ingest(run.solutions[k - 1])
        m = s.process(t, run.epochs[vid][k], run.corrections[k], run.uwb[vid].get(t, ()))
        assert m == run.messages[k][vid]
        assert NodeMessage.model_validate_json(m.model_dump_json(by_alias=True)) == m


# -- VehicleStep: ingest ------------------------------------------------------------------------


def _solution(t: GpsTime, positions: dict[str, tuple[float, float, float]]) -> SolutionMessage:
    states = [
        VehicleState(
            vehicle_id=vid,
            position_ecef_m=p,
            covariance_m2=[0.25, 0, 0, 0, 0.25, 0, 0, 0, 0.25],
            antenna_height_m=1.7,
            n_pseudoranges=8,
            n_ranges=0,
            plane_used=False,
            has_gnss_fix=True,
        )
        for vid, p in sorted(positions.items())
    ]
    return SolutionMessage(
        fleet=FLEET, method="pc", seq=0, epoch=epoch_time(t), vehicles=states, solve_time_s=0.0
    )


def _positions(run: Run, k: int) -> dict[str, tuple[float, float, float]]:
    return {v.vehicle_id: v.position_ecef_m for v in run.solutions[k].vehicles}


def test_ingest_ignores_solutions_before_first_epoch(run: Run) -> None:
    """Before its first message, and for epochs before it, a vehicle keeps no history (a late joiner)."""
    s = _vehicle(run.rec, "u1", "pc")
    s.ingest(_solution(run.times[0], _positions(run, 0)))
    assert len(s.history) == 0 and s.first_epoch is None
    s.process(run.times[2], run.epochs["u1"][2], run.corrections[2])
    s.ingest(_solution(run.times[1], _positions(run, 1)))
    assert len(s.history) == 0
    s.ingest(_solution(run.times[2], _positions(run, 2)))
    assert len(s.history) == 4 and s.history.vehicle_ids == IDS


def test_ingest_pc_self_keeps_only_own_state(run: Run) -> None:
    """Method pc-self stores only the vehicle's own solved position, never the other vehicles'."""
    s = _vehicle(run.rec, "u2", "pc-self")
    assert s.method.planes == "self"
    s.process(run.times[0], run.epochs["u2"][0], run.corrections[0])
    for k in range(3):
        s.ingest(_solution(run.times[k], _positions(run, k)))
    assert s.history.vehicle_ids == ("u2",) and len(s.history) == 3


def test_ingest_without_planes_keeps_no_history(run: Run) -> None:
    """A method without planes keeps no plane history (nothing to fit) but still follows its own fused position."""
    ep1 = run.epochs["u1"][1]
    assert ep1 is not None
    few = ObsEpoch(ep1.time, ep1.sats[:3])  # too few satellites for SPP
    followed, alone = _vehicle(run.rec, "u1", "mci"), _vehicle(run.rec, "u1", "mci")
    for s in (followed, alone):
        s.process(run.times[0], run.epochs["u1"][0], run.corrections[0])
    followed.ingest(_solution(run.times[0], _positions(run, 0)))
    assert len(followed.history) == 0
    # without a fix, satellites are modelled at the fused position; with none known they cannot be
    m = followed.process(run.times[1], few, run.corrections[1])
    assert not m.spp.ok and len(m.satellites) == 3
    m_alone = alone.process(run.times[1], few, run.corrections[1])
    assert not m_alone.spp.ok and len(m_alone.satellites) == 0


def test_ingest_uses_fused_position_without_fix(run: Run) -> None:
    """After ingesting, a vehicle without a receiver epoch still gets a plane centred on its fused position."""
    s = _vehicle(run.rec, "u3", "pc")
    s.process(run.times[0], run.epochs["u3"][0], run.corrections[0])
    for k in range(N_EPOCHS - 1):
        s.ingest(_solution(run.times[k], _positions(run, k)))
    m = s.process(run.times[N_EPOCHS - 1], None)
    assert not m.spp.ok
    assert m.plane is not None and m.plane.reason != "no position to centre the fitting region"
    assert m.plane.n_points_initial > 0


# -- FusionStep with a stand-in estimator --------------------------------------------------------


@dataclass
class Recorder:
    """A stand-in estimator: remembers its input, estimates each vehicle at its SPP position."""

    inputs: list[EpochInput] = field(default_factory=list)
    nan_cov: set[str] = field(default_factory=set)

    def step(self, epoch: EpochInput) -> FleetSolution:
        self.inputs.append(epoch)
        est = {}
        for vid, v in epoch.vehicles.items():
            if v.spp_position is None:
                continue
            cov = np.full((3, 3), np.nan) if vid in self.nan_cov else np.eye(3) * 4.0
            est[vid] = VehicleEstimate(
                vid,
                epoch.time,
                np.asarray(v.spp_position),
                cov,
                {"G": 1e-7},
                n_pseudoranges=len(v.pseudoranges),
                n_ranges=sum(1 for r in epoch.ranges if vid in (r.a, r.b)),
                plane_used=v.plane is not None,
            )
        return FleetSolution(epoch.time, est, 0.125, {"pseudorange": 3})


def _fusion(**cfg: Any) -> tuple[FusionStep, Recorder]:
    rec = Recorder()
    spec = MethodSpec("stand-in", "records its inputs", "fleet", True, True, factory=lambda: rec)
    return FusionStep(FLEET, spec, FusionStepConfig(**cfg)), rec


def _with_ranges(m: NodeMessage, *peers: tuple[str, float]) -> NodeMessage:
    return m.model_copy(update={"ranges": [RangeReport(to=p, range_m=r, sigma_m=0.3) for p, r in peers]})


def test_inputs_keep_only_used_satellites(run: Run) -> None:
    """Only satellites the vehicle used become pseudoranges, with the message's values converted."""
    f, _ = _fusion()
    k = 2
    ep = f.inputs(run.times[k], run.messages[k])
    assert sorted(ep.vehicles) == list(IDS) and ep.time == run.times[k]
    for vid, m in run.messages[k].items():
        used = [s for s in m.satellites.rows() if s.used]
        assert len(used) < len(m.satellites)  # some are excluded at this epoch
        prs = ep.vehicles[vid].pseudoranges
        assert isinstance(prs, PseudorangeColumns)  # the server's form: columns, not an object each
        assert list(prs.sats) == [s.sat for s in used]
        for i, s in enumerate(used):
            assert (prs.rho_m[i], prs.sat_clock_s[i], prs.sigma_m[i]) == (s.rho_m, s.sat_clock_s, s.sigma_m)
            assert tuple(prs.sat_pos_m[i]) == s.sat_pos_ecef_m
            assert prs.elevation_rad[i] == math.radians(s.elevation_deg)
            assert prs.cn0_dbhz[i] == s.cn0_dbhz


def test_inputs_vehicle_fields(run: Run) -> None:
    """Velocity gets the method's sigma, drift and SPP position pass through, only available planes pass."""
    f, _ = _fusion()
    k = N_EPOCHS - 1
    ep = f.inputs(run.times[k], run.messages[k])
    for vid, m in run.messages[k].items():
        v = ep.vehicles[vid]
        assert m.velocity is not None and v.velocity is not None
        assert tuple(v.velocity.velocity_mps) == m.velocity.velocity_ecef_mps
        assert v.velocity.sigma_mps == f.method.velocity_sigma_mps
        assert v.clock_drift_mps == m.velocity.clock_drift_mps
        assert v.spp_position is not None and tuple(v.spp_position) == m.spp.position_ecef_m
        assert m.plane is not None
        if m.plane.status == "unavailable":
            assert v.plane is None
        else:
            assert v.plane is not None
            assert (tuple(v.plane.normal), v.plane.d_m, v.plane.sigma_m, v.plane.status) == (
                m.plane.normal,
                m.plane.d_antenna_m,
                m.plane.sigma_m,
                m.plane.status,
            )
    assert ep.vehicles["u3"].plane is not None


def test_inputs_without_fix_or_cn0(run: Run) -> None:
    """A vehicle without an SPP fix has no initial position; a satellite without C/N0 gets NaN."""
    f, _ = _fusion()
    m = run.messages[1]["u1"]
    i = m.satellites.used.index(True)
    sats = m.satellites.rows()
    sats[i] = sats[i].model_copy(update={"cn0_dbhz": None})
    spp = m.spp.model_copy(update={"ok": False, "position_ecef_m": None})
    bad = m.model_copy(
        update={"spp": spp, "satellites": SatelliteColumns.from_rows(sats), "velocity": None, "plane": None}
    )
    v = f.inputs(run.times[1], {"u1": bad}).vehicles["u1"]
    assert v.spp_position is None and v.velocity is None and v.clock_drift_mps is None and v.plane is None
    prs = v.pseudoranges
    assert isinstance(prs, PseudorangeColumns)
    assert prs.sats[0] == sats[i].sat and math.isnan(prs.cn0_dbhz[0])
    assert np.isfinite(prs.cn0_dbhz[1:]).all()


def test_one_range_per_pair_first_reporter_wins(run: Run) -> None:
    """Both vehicles of a pair reporting a range give one range, the first in id order, with the pair sorted."""
    f, _ = _fusion()
    msgs = dict(run.messages[0])
    msgs["u1"] = _with_ranges(msgs["u1"], ("u3", 30.0), ("u2", 8.0))
    msgs["u2"] = _with_ranges(msgs["u2"], ("u1", 8.4))
    msgs["u3"] = _with_ranges(msgs["u3"], ("u1", 30.3), ("u4", 5.0))
    msgs["u4"] = _with_ranges(msgs["u4"])
    ep = f.inputs(run.times[0], msgs)
    assert [(r.a, r.b, r.range_m) for r in ep.ranges] == [
        ("u1", "u2", 8.0),
        ("u1", "u3", 30.0),
        ("u3", "u4", 5.0),
    ]
    assert all(r.sigma_m == 0.3 for r in ep.ranges)


def test_ranges_to_silent_vehicles_dropped(run: Run) -> None:
    """A range to a vehicle that sent no message this epoch is dropped."""
    f, _ = _fusion()
    msgs = {
        "u1": _with_ranges(run.messages[0]["u1"], ("u2", 8.0), ("u4", 40.0)),
        "u2": _with_ranges(run.messages[0]["u2"]),
    }
    ep = f.inputs(run.times[0], msgs)
    assert [(r.a, r.b) for r in ep.ranges] == [("u1", "u2")]


def _all_pairs(run: Run, k: int) -> dict[str, NodeMessage]:
    peers = {vid: [(p, 10.0 + i) for i, p in enumerate(IDS) if p > vid] for vid in IDS}
    return {vid: _with_ranges(run.messages[k][vid], *peers[vid]) for vid in IDS}


def test_interruption_rate_one_drops_all_ranges(run: Run) -> None:
    """Interruption rate 1.0 removes every range; 0.0 removes none."""
    msgs = _all_pairs(run, 0)
    assert len(_fusion()[0].inputs(run.times[0], msgs).ranges) == 6
    assert _fusion(interruption_rate=1.0)[0].inputs(run.times[0], msgs).ranges == ()


def test_interruption_decided_by_time(run: Run) -> None:
    """Which ranges are removed depends on the epoch time (not on a counter): a restarted step decides alike."""
    t = run.times[0] + 3600.0 * 5  # any time: the epoch index is round(t.seconds / interval)
    msgs = _all_pairs(run, 0)
    n_kept = []
    for seed in range(4):
        long_running, _ = _fusion(interruption_rate=0.5, interruption_seed=seed, interval_s=1.0)
        long_running.inputs(run.times[0], msgs)
        restarted, _ = _fusion(interruption_rate=0.5, interruption_seed=seed, interval_s=1.0)
        kept = [(r.a, r.b) for r in restarted.inputs(t, msgs).ranges]
        assert kept == [(r.a, r.b) for r in long_running.inputs(t, msgs).ranges]
        k = round(t.seconds / 1.0)
        expected = [(a, b) for a in IDS for b in IDS if a < b and not interrupt_range((a, b), k, 0.5, seed)]
        assert kept == expected
        n_kept.append(len(kept))
    assert min(n_kept) < 6 and max(n_kept) > 0  # the rate removes some, not all


def test_solve_wraps_estimates(run: Run) -> None:
    """solve returns the estimates as a SolutionMessage with the vehicles' own reports attached."""
    f, est = _fusion()
    k = N_EPOCHS - 1
    msgs = {
        vid: m.model_copy(update={"sent_unix_s": 100.0 + i})
        for i, (vid, m) in enumerate(run.messages[k].items())
    }
    est.nan_cov.add("u2")
    sol = f.solve(run.times[k], msgs, missing=["u9", "u5", "u7"])
    assert isinstance(sol, SolutionMessage)
    assert (sol.fleet, sol.method, sol.seq) == (FLEET, "stand-in", 0)
    assert gps_time(sol.epoch) == run.times[k]
    assert sol.missing == ["u5", "u7", "u9"]
    assert sol.solve_time_s == 0.125 and sol.factor_counts == {"pseudorange": 3}
    assert sol.oldest_node_sent_unix_s == 100.0
    assert [v.vehicle_id for v in sol.vehicles] == list(IDS)
    for v in sol.vehicles:
        m = msgs[v.vehicle_id]
        assert v.position_ecef_m == m.spp.position_ecef_m
        assert v.antenna_height_m == m.antenna_height_m
        assert v.n_satellites == sum(m.satellites.used) == v.n_pseudoranges
        assert v.spp_ok == m.spp.ok and v.clocks_s == {"G": 1e-7}
        assert m.plane is not None and v.plane_status == m.plane.status
        assert v.plane == plane_summary(m.plane)
        assert v.covariance_m2 == (None if v.vehicle_id == "u2" else [4.0, 0, 0, 0, 4.0, 0, 0, 0, 4.0])
    assert len(est.inputs) == 1


def test_solve_seq_increments_and_skips_unestimated(run: Run) -> None:
    """seq counts solutions from 0; a vehicle the estimator did not estimate is not in the solution."""
    f, _ = _fusion()
    m = run.messages[0]["u1"]
    nofix = m.model_copy(update={"spp": m.spp.model_copy(update={"ok": False, "position_ecef_m": None})})
    seqs = []
    for k in range(3):
        msgs = dict(run.messages[k])
        msgs["u1"] = nofix
        sol = f.solve(run.times[k], msgs)
        seqs.append(sol.seq)
        assert [v.vehicle_id for v in sol.vehicles] == ["u2", "u3", "u4"]
        assert sol.missing == [] and sol.oldest_node_sent_unix_s is None
    assert seqs == [0, 1, 2] and f.seq == 3


def test_solve_with_the_factor_graph(run: Run) -> None:
    """With the real pc estimator the short run's solutions are numbered, complete and near the truth."""
    assert [s.seq for s in run.solutions] == list(range(N_EPOCHS))
    for k, sol in enumerate(run.solutions):
        assert [v.vehicle_id for v in sol.vehicles] == list(IDS)
        assert sol.method == "pc" and gps_time(sol.epoch) == run.times[k]
        for v in sol.vehicles:
            truth = run.rec.truth_at(v.vehicle_id)[run.times[k]]
            assert (
                np.linalg.norm(np.subtract(v.position_ecef_m, truth)) < 5.0
            )  # DGNSS + UWB: about 1 m on these epochs


# -- wire helpers -------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "t",
    [
        GpsTime(2320, 115800.0),
        GpsTime(2320, 115800.004),
        GpsTime(0, 0.0),
        GpsTime(2320, 604799.999999),
        GpsTime(1, 1 / 3),
    ],
)
def test_epoch_time_round_trip(t: GpsTime) -> None:
    """GpsTime -> EpochTime -> GpsTime is exact, also through JSON."""
    e = epoch_time(t)
    assert isinstance(e, EpochTime)
    assert gps_time(e) == t
    assert gps_time(EpochTime.model_validate_json(e.model_dump_json())) == t


def test_cov9() -> None:
    """A finite 3x3 covariance becomes 9 row-major Python floats; any NaN or inf gives None."""
    c = np.arange(9.0).reshape(3, 3)
    out = cov9(c)
    assert out == [0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0]
    assert out is not None and all(type(x) is float for x in out)
    for bad in (np.nan, np.inf):
        c2 = c.copy()
        c2[1, 2] = bad
        assert cov9(c2) is None
    assert cov9(np.full((3, 3), np.nan)) is None


def test_tuple3_gives_python_floats() -> None:
    """tuple3 turns a numpy vector into a tuple of Python floats (JSON-safe, exact)."""
    t = tuple3(np.array([1.5, -2.0, 1e7], dtype=np.float64))
    assert t == (1.5, -2.0, 1e7) and all(type(x) is float for x in t)


def test_stable_seed_does_not_use_hash() -> None:
    """Seeds come from CRC32 of strings and masked ints, so every process derives the same generator."""
    assert stable_seed(0, "u1", 5) == [0, zlib.crc32(b"u1"), 5]
    assert stable_seed(-1) == [0xFFFFFFFF]


def test_plane_report_of_unavailable_plane() -> None:
    """An unavailable plane's wire form has its reason and counts but no normal, offset or sigma."""
    p = construct_plane(np.zeros((0, 3)), 1.7, PlaneConfig(), np.random.default_rng(0))
    r = plane_report(p)
    assert r.status == "unavailable" and r.reason == "no fitting points"
    assert r.normal is None and r.d_antenna_m is None and r.sigma_m is None
    assert r.residual_max_m is None  # NaN residual is sent as "unknown"
    assert (r.n_points_initial, r.n_points_used) == (0, 0)
    s = plane_summary(r)
    assert s is not None and (s.status, s.reason) == ("unavailable", "no fitting points")


def test_plane_report_of_degenerate_plane() -> None:
    """Too few points for a plane: unavailable, the count kept, the reason passed on."""
    pts = np.array([[-2169358.0, 4387164.0, 4076272.0], [-2169359.0, 4387164.0, 4076272.0]])
    r = plane_report(construct_plane(pts, 1.7, PlaneConfig(), np.random.default_rng(0)))
    assert r.status == "unavailable" and r.reason is not None and "degenerate" in r.reason
    assert r.n_points_initial == 2


def test_plane_report_of_available_plane() -> None:
    """An available plane's wire form carries its geometry; sigma adds the offset uncertainty in quadrature."""
    ref = np.array([-2169358.0, 4387164.0, 4076272.0])
    g = np.random.default_rng(1)
    enu = np.column_stack([g.uniform(-20, 20, 20), g.uniform(-20, 20, 20), g.normal(0.0, 0.02, 20)])
    pts = enu_to_ecef(enu, ref)
    p = construct_plane(pts, 1.5, PlaneConfig(), np.random.default_rng(0))
    assert p.available
    r = plane_report(p, 0.4)
    assert r.status == p.status.value
    assert r.normal == tuple3(p.normal) and r.centroid_ecef_m == tuple3(p.centroid)
    assert (r.d_antenna_m, r.d_road_m) == (p.d_antenna, p.d_road)
    assert r.offset_sigma_m == 0.4 and r.sigma_m == math.hypot(p.sigma_m, 0.4)
    assert plane_report(p).sigma_m == p.sigma_m
    assert (r.n_points_initial, r.n_points_used) == (20, p.n_points_used)
    s = plane_summary(r)
    assert s is not None and (s.sigma_m, s.offset_sigma_m, s.residual_rms_m) == (
        r.sigma_m,
        0.4,
        r.residual_rms_m,
    )
    assert plane_summary(None) is None


def test_plane_report_is_valid_wire(run: Run) -> None:
    """Every plane report the steps produced validates again as a PlaneReport (unit normal, bounds)."""
    for msgs in run.messages:
        for m in msgs.values():
            assert m.plane is not None
            assert PlaneReport.model_validate(m.plane.model_dump()) == m.plane
