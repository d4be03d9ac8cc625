"""Admission of valid but hostile node messages at the fusion server (issue 13).

One test per attack the issue reproduced (future, past, off-grid, 20,000 epochs, rate, absurd
plane, displaced fix, duplicate, conflicting duplicate, replayed seq, fake liveliness token), each
driving a `FusionServer` in-process without a bus (`handle_node` / `ready_epoch` / `solve` with
explicit times), and the genuine side: the bundled recording's node messages go through the server
with 0 rejections and the same positions as `coplane eval`, and the thresholds stay far above what
genuine messages (bundled, simulated dense urban, real data) measure.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from coplane.bus import encode
from coplane.evaluate.runner import run_method
from coplane.fusion_server.admission import HISTORY_DEPTH, Admission, AdmissionConfig
from coplane.fusion_server.plausibility import (
    GENUINE_MAX,
    SPP_HEIGHT_M,
    plane_distance_m,
    plane_problem,
    plane_tilt_deg,
    spp_height_m,
    spp_residual_m,
)
from coplane.fusion_server.server import FusionServer
from coplane.fusion_server.settings import FusionSettings
from coplane.gtime import GpsTime
from coplane.messages import NodeMessage, PlaneReport, SatelliteColumns, SolutionMessage, SppReport
from coplane.recording.reader import open_recording
from coplane.sim import ensure_default_recording
from coplane.sim.generate import simulate
from coplane.steps import epoch_time, gps_time

WEEK_S = 7 * 86400.0


@dataclass
class Genuine:
    recording: Path
    epochs: list[dict[str, NodeMessage]]  # per epoch, in order
    solutions: list[SolutionMessage]  # the in-process reference


def _run(rec: Path) -> Genuine:
    epochs: list[dict[str, NodeMessage]] = []
    sols: list[SolutionMessage] = []

    def keep(sol: SolutionMessage, m: dict[str, NodeMessage]) -> None:
        sols.append(sol)
        epochs.append(dict(m))

    run_method(open_recording(rec), "pc", on_solution=keep, jobs=1)
    return Genuine(rec, epochs, sols)


@pytest.fixture(scope="module")
def bundled() -> Genuine:
    """The bundled recording's genuine node messages (4 vehicles x 600 epochs) and solutions."""
    return _run(ensure_default_recording())


def _server(g: Genuine, **kw: Any) -> FusionServer:
    s = FusionServer(FusionSettings(recording=g.recording, db="none", **kw))
    s.live = set(s.known)
    s.started = -1e9  # past the lockstep startup wait (counted from the first admitted message,
    s.admission.first_admit_s = -1e9  # and never before the server's start)
    return s


def _put(s: FusionServer, m: NodeMessage, now: float) -> None:
    s.handle_node(s.keys.node(m.vehicle_id), encode(m), now=now)


def _solve_ready(s: FusionServer, now: float) -> list[SolutionMessage]:
    out = []
    while (t := s.ready_epoch(now)) is not None:
        if (sol := s.solve(t)) is not None:
            out.append(sol)
    return out


def _at(m: NodeMessage, t: GpsTime, **upd: Any) -> NodeMessage:
    """`m` re-stamped at epoch `t` (receiver tag moved alike)."""
    dt = t - gps_time(m.epoch)
    return m.model_copy(
        update={"epoch": epoch_time(t), "rx_time": epoch_time(gps_time(m.rx_time) + dt), **upd}
    )


def _invariant(s: FusionServer) -> None:
    """received = used + rejected + late + duplicate, for every vehicle once nothing is pending."""
    pending = {v: sum(1 for m in s.pending.values() if v in m) for v in s.known}
    for v, c in s.counters.items():
        assert c["received"] == c["used"] + c["rejected"] + c["late"] + c["duplicate"] + pending[v], (v, c)


def _feed_lockstep(s: FusionServer, g: Genuine, epochs: range, now: float = 0.0) -> list[SolutionMessage]:
    out = []
    for k in epochs:
        for _, m in sorted(g.epochs[k].items()):
            _put(s, m, now)
        out += _solve_ready(s, now)
        now += 0.01
    return out


def _feed_realtime(s: FusionServer, g: Genuine, epochs: range, t0: float = 0.0) -> Iterator[float]:
    """Realtime: epoch k's messages at t0 + k, the server polled every 0.1 s; yields each time."""
    for k in epochs:
        now = t0 + k
        for _, m in sorted(g.epochs[k].items()):
            _put(s, m, now)
        for j in range(10):
            yield now + 0.1 * j


# -- the genuine side: 0 rejections --------------------------------------------------------------
def test_bundled_recording_is_admitted_whole_and_solved_alike(bundled: Genuine) -> None:
    """Every genuine message of the bundled recording is used, and lockstep positions are the same
    bits as `coplane eval`; the rate limit's lowest bucket level stays far from empty."""
    s = _server(bundled)
    sols = _feed_lockstep(s, bundled, range(len(bundled.epochs)))
    assert len(sols) == len(bundled.solutions)
    for a, b in zip(sols, bundled.solutions, strict=True):
        assert [v.position_ecef_m for v in a.vehicles] == [v.position_ecef_m for v in b.vehicles]
    d = s.diagnostics()
    assert d.rejected_by_reason == {}
    assert all(c.rejected == 0 and c.late == 0 and c.used == c.received for c in d.vehicles.values())
    assert d.pending_epochs == 0 and d.pending_limit == s.admission.config.pending_limit
    assert s.admission.min_tokens >= s.s.rate_limit_burst - 2


def test_realtime_genuine_run_solves_every_epoch_on_time(bundled: Genuine) -> None:
    """Realtime: every epoch solved within the deadline, none late, nothing rejected."""
    s = _server(bundled, pace="realtime")
    n = 60
    solved: list[tuple[float, SolutionMessage]] = []
    for now in _feed_realtime(s, bundled, range(n)):
        solved += [(now, sol) for sol in _solve_ready(s, now)]
    assert [sol.vehicles for _, sol in solved] == [e.vehicles for e in bundled.solutions[:n]]
    assert all(now - k <= s.s.deadline_s + 0.11 for k, (now, _) in enumerate(solved))
    assert sum(s.rejected_by_reason.values()) == 0
    assert all(c["late"] == 0 for c in s.counters.values())


def test_history_replay_after_a_restart_is_not_rate_limited(bundled: Genuine) -> None:
    """A restarted server receives up to HISTORY_DEPTH cached messages per vehicle at once (the
    agents' publication caches) plus the live ones: none is rate-limited or rejected."""
    s = _server(bundled, pace="realtime")
    k0 = 200
    for k in range(k0 - HISTORY_DEPTH, k0 + 1):  # the caches, all at the same instant
        for _, m in sorted(bundled.epochs[k].items()):
            _put(s, m, 0.0)
    for now in _feed_realtime(s, bundled, range(k0 + 1, k0 + 10), t0=-float(k0)):
        _solve_ready(s, now)
    assert sum(s.rejected_by_reason.values()) == 0
    assert s.epochs_solved >= HISTORY_DEPTH
    assert s.admission.min_tokens >= s.s.rate_limit_burst - HISTORY_DEPTH - 2
    _invariant(s)


def _all_messages(g: Genuine) -> list[NodeMessage]:
    return [m for ep in g.epochs for _, m in sorted(ep.items())]


def _measure(msgs: list[NodeMessage]) -> dict[str, float]:
    res = [r for m in msgs if m.spp.ok and (r := spp_residual_m(m)) is not None]
    hs = [h for m in msgs if (h := spp_height_m(m)) is not None]
    planes = [m for m in msgs if m.plane is not None and m.plane.status != "unavailable"]
    tilt = [
        plane_tilt_deg(m.plane, p) for m in planes if (p := m.spp.position_ecef_m or m.plane.centroid_ecef_m)
    ]
    dist = [
        abs(plane_distance_m(m.plane, p))
        for m in planes
        if (p := m.spp.position_ecef_m or m.plane.centroid_ecef_m)
    ]
    return {
        "residual": max(res, default=0.0),
        "h_lo": min(hs, default=0.0),
        "h_hi": max(hs, default=0.0),
        "tilt": max(tilt, default=0.0),
        "dist": max(dist, default=0.0),
    }


def _check_genuine(msgs: list[NodeMessage]) -> dict[str, float]:
    """Every genuine message passes the plausibility checks with a wide margin (half the threshold)."""
    cfg = AdmissionConfig()
    m = _measure(msgs)
    assert m["residual"] <= max(GENUINE_MAX["spp_residual_m"], 1.0) * 1.01 <= cfg.spp_residual_m / 2  # type: ignore[operator]
    assert SPP_HEIGHT_M[0] / 2 <= m["h_lo"] and m["h_hi"] <= SPP_HEIGHT_M[1] / 2
    assert m["tilt"] <= GENUINE_MAX["plane_tilt_deg"] * 1.01 <= cfg.plane_tilt_deg / 2  # type: ignore[operator]
    assert m["dist"] <= GENUINE_MAX["plane_distance_m"] * 1.01 <= cfg.plane_distance_m / 2  # type: ignore[operator]
    a = Admission(AdmissionConfig(interval_s=1.0, rate_per_s=1e9, burst=1e9))
    for k, msg in enumerate(msgs):  # each vehicle alone (no window), in order
        v = a.check(
            msg,
            gps_time(msg.epoch),
            bytes([k % 256]) * 16,
            0.0,
            solved_up_to=None,
            pending_epochs=0,
            epoch_pending=True,
        )
        assert v.outcome == "admit" and not v.plane_dropped, (msg.vehicle_id, msg.epoch, v)
        a.admitted(msg.vehicle_id, gps_time(msg.epoch), msg.seq, bytes([k % 256]) * 16, 0.0)
        a.solved(gps_time(msg.epoch))
    return m


def test_genuine_maxima_bundled_and_dense_urban(bundled: Genuine, tmp_path: Path) -> None:
    """The measured genuine maxima behind the thresholds (GENUINE_MAX): bundled and dense urban."""
    _check_genuine(_all_messages(bundled))
    dense = _run(simulate("dense-urban", tmp_path / "dense", vehicles=4, duration_s=120, seed=11))
    _check_genuine(_all_messages(dense))


@pytest.mark.realdata
@pytest.mark.parametrize(
    "name",
    [
        "matrtklib_nagoya_static_20240624",
        "urbannav_hk_tst_20200603_static_f9p",
        "hk_klt_20210610_f9p_rover_hksc_base",
    ],
)
def test_genuine_maxima_real_data(real_data: Path, name: str) -> None:
    """Real receivers (open sky, an urban canyon, a car in Kowloon): every message admitted."""
    _check_genuine(_all_messages(_run(real_data / name)))


# -- time --------------------------------------------------------------------------------------------
def test_future_epoch_cannot_freeze_the_realtime_pace(bundled: Genuine) -> None:
    """A message a week ahead is rejected; one inside the window waits for the fleet instead of
    being solved first (which made every genuine epoch late)."""
    s = _server(bundled, pace="realtime")
    ref = _server(bundled, pace="realtime")
    n = 40
    got, want = [], []
    feed, clean = _feed_realtime(s, bundled, range(n)), _feed_realtime(ref, bundled, range(n))
    for i, (now, _) in enumerate(zip(feed, clean, strict=True)):
        if i == 35:  # epoch 3: u2 sends a week ahead, and its epoch-23 message already
            m = bundled.epochs[3]["u2"]
            _put(s, _at(m, gps_time(m.epoch) + WEEK_S, seq=m.seq + 1), now)
            _put(s, bundled.epochs[23]["u2"], now)  # inside the window: waits for the fleet
        got += _solve_ready(s, now)
        want += _solve_ready(ref, now)
    assert s.rejected_by_reason == {"too-far-ahead": 1}
    assert s.counters["u2"]["duplicate"] == 1  # the genuine epoch-23 message, later
    assert len(got) == len(want) == n
    assert [a.vehicles for a in got] == [b.vehicles for b in want]
    assert all(c["late"] == 0 for c in s.counters.values())


def test_lone_first_sender_cannot_set_the_realtime_epoch(bundled: Genuine) -> None:
    """At start nobody has a reference: a message a week ahead sent before the fleet speaks is
    admitted (alone), but not solved; once the fleet speaks it is dropped and the fleet's epochs
    are solved, none late."""
    s = _server(bundled, pace="realtime")
    s.started = 0.0
    m = bundled.epochs[0]["u4"]
    _put(s, _at(m, gps_time(m.epoch) + WEEK_S), 0.0)
    assert not _solve_ready(s, 1.0)
    solved = []
    for k in range(20):
        for vid in ("u1", "u2", "u3"):
            _put(s, bundled.epochs[k][vid], 2.0 + k)
        for j in range(10):
            solved += _solve_ready(s, 2.0 + k + 0.1 * j)
    assert [sol.epoch for sol in solved] == [b.epoch for b in bundled.solutions[:20]]
    assert s.rejected_by_reason == {"too-far-ahead": 1}
    assert all(c["late"] == 0 for c in s.counters.values())
    _invariant(s)


@pytest.mark.parametrize("pace", ["lockstep", "realtime"])
def test_lone_first_sender_cannot_set_a_stray_epoch(bundled: Genuine, pace: str) -> None:
    """Before the fleet speaks, messages a week and a minute before and a week after its first
    epoch are admitted (nobody to compare with) but never solved: dropped once the fleet speaks."""
    s = _server(bundled, pace=pace)
    s.started = 0.0
    m = bundled.epochs[0]["u4"]
    _put(s, _at(m, gps_time(m.epoch) + (-WEEK_S), seq=100), 0.0)
    _put(s, _at(m, gps_time(m.epoch) + WEEK_S, seq=200), 0.0)
    _put(s, _at(m, gps_time(m.epoch) + (-60.0), seq=150), 0.0)  # a minute before the fleet's start
    assert len(s.pending) == 3 and not _solve_ready(s, 1.0)
    solved = []
    for k in range(20):
        for vid in ("u1", "u2", "u3"):
            _put(s, bundled.epochs[k][vid], 2.0 + k)
        for j in range(10):
            solved += _solve_ready(s, 2.0 + k + 0.1 * j)
    if pace == "lockstep":
        solved += _solve_ready(s, 100.0)  # u4 is live but silent: one stall, then no more
    assert [sol.epoch for sol in solved] == [b.epoch for b in bundled.solutions[:20]]
    assert s.rejected_by_reason == {"too-far-ahead": 1, "too-far-behind": 2}
    _invariant(s)


def test_start_wait_counts_from_the_fleets_first_message(bundled: Genuine) -> None:
    """A lockstep server up long before its fleet still gives a slow agent `startup_wait_s` from
    the fleet's first message (a load generator putting 1000 vehicles' first epoch takes seconds):
    counted from the server's start, the first epoch was solved without it and its message was
    late (at 1000 vehicles a whole epoch went unanswered)."""
    s = _server(bundled)
    s.started, s.admission.first_admit_s = 0.0, None
    s.live = {"u1", "u2", "u3"}  # u4's agent is not up yet
    for vid in ("u1", "u2", "u3"):
        _put(s, bundled.epochs[0][vid], 100.0)
    assert not _solve_ready(s, 105.0)  # 105 s after the server's start, 5 s after the fleet's
    s.live.add("u4")
    _put(s, bundled.epochs[0]["u4"], 106.0)
    sols = _solve_ready(s, 106.0)
    assert [sorted(v.vehicle_id for v in sol.vehicles) for sol in sols] == [["u1", "u2", "u3", "u4"]]
    assert all(c["late"] == 0 for c in s.counters.values())
    _invariant(s)


def test_realtime_start_wait_never_fills_pending(bundled: Genuine) -> None:
    """A fast realtime replay (50 epochs a wall second) with a vehicle that never speaks: the start
    wait ends before the pending bound could refuse a genuine epoch."""
    s = _server(bundled, pace="realtime", deadline_s=0.01)
    s.started = 0.0
    solved = []
    for k in range(200):
        now = 0.02 * k
        for vid in ("u1", "u2", "u3"):
            _put(s, bundled.epochs[k][vid], now)
        solved += _solve_ready(s, now + 0.015)
    solved += _solve_ready(s, 100.0)
    assert len(solved) == 200 and sum(s.rejected_by_reason.values()) == 0
    assert all(c["late"] == 0 for c in s.counters.values())


def test_future_epoch_cannot_remove_a_vehicle_in_lockstep(bundled: Genuine) -> None:
    s = _server(bundled)
    m = bundled.epochs[2]["u2"]
    sols = _feed_lockstep(s, bundled, range(2))
    _put(s, _at(m, gps_time(m.epoch) + WEEK_S, seq=m.seq + 5), 0.5)
    sols += _feed_lockstep(s, bundled, range(2, 20), now=1.0)
    assert s.rejected_by_reason == {"too-far-ahead": 1}
    assert all("u2" in [v.vehicle_id for v in sol.vehicles] for sol in sols)
    assert [sol.vehicles for sol in sols] == [sol.vehicles for sol in bundled.solutions[:20]]


def test_past_epoch_is_late_and_changes_nothing(bundled: Genuine) -> None:
    s = _server(bundled)
    _feed_lockstep(s, bundled, range(5))
    m = bundled.epochs[1]["u3"]
    for dt in (0.0, -1.0, -WEEK_S):
        _put(s, _at(m, gps_time(m.epoch) + dt), 1.0)
    # the identical message the solve of epoch 1 used is a duplicate (a lockstep re-send that
    # crossed the solution), the others are late
    assert s.counters["u3"]["late"] == 2 and s.counters["u3"]["duplicate"] == 1 and not s.pending
    _put(s, _at(m, gps_time(m.epoch), seq=m.seq + 1000), 1.0)  # other bytes for that epoch: late
    assert s.counters["u3"]["late"] == 3
    _invariant(s)


def test_off_grid_epoch_is_rejected(bundled: Genuine) -> None:
    s = _server(bundled)
    _feed_lockstep(s, bundled, range(3))
    m = bundled.epochs[3]["u1"]
    for frac in (0.5, 0.01, 0.999):
        _put(s, _at(m, gps_time(m.epoch) + frac), 1.0)
    assert s.rejected_by_reason == {"off-grid": 3} and not s.pending
    _put(s, m, 1.0)  # the genuine one still gets in
    assert s.pending[gps_time(m.epoch)]["u1"] == m
    _invariant(s)


def test_twenty_thousand_epochs_keep_pending_bounded(bundled: Genuine) -> None:
    """20,000 distinct on-grid epochs from one vehicle (consistent seqs, no rate limit): pending
    never grows past its bound, reported in the diagnostics; the genuine fleet goes on."""
    s = _server(bundled, rate_limit_burst=1e9)
    lean = bundled.epochs[0]["u4"].model_copy(
        update={"satellites": SatelliteColumns(), "plane": None, "ranges": []}
    )
    t0 = gps_time(lean.epoch)
    limit = s.admission.config.pending_limit
    assert limit == 30 + HISTORY_DEPTH + 16
    for k in range(20_000):
        _put(s, _at(lean, t0 + k, seq=k), 0.0)
        assert len(s.pending) <= limit
    d = s.diagnostics()
    assert d.pending_epochs == limit == d.pending_limit
    assert s.rejected_by_reason == {"pending-full": 20_000 - limit}
    # with the default rate limit most of such a flood never gets that far
    r = _server(bundled)
    for k in range(2_000):
        _put(r, _at(lean, t0 + k, seq=k), 0.0)
    assert r.rejected_by_reason["rate-limited"] == 2_000 - int(r.s.rate_limit_burst)
    assert len(r.pending) <= limit


def test_window_follows_the_fleet_not_one_vehicle(bundled: Genuine) -> None:
    """The fleet's current epoch is the lower median of the vehicles' latest epochs: one vehicle
    cannot move it; a vehicle alone (start, resume, rejoin after a gap) is its own reference."""
    a = Admission(AdmissionConfig(interval_s=1.0, max_ahead_s=30.0))
    t0 = gps_time(bundled.epochs[0]["u1"].epoch)
    for i, vid in enumerate(["u1", "u2", "u3"]):
        a.admitted(vid, t0, 0, bytes([i]) * 16, 0.0)
    a.admitted("u4", t0 + 25.0, 0, b"x" * 16, 0.0)  # inside the window
    assert a.reference(0.0, None) == t0 and a.solve_limit(0.0, None) == t0
    assert a.outside_window(t0 + 31.0, 0.0, None) == "too-far-ahead"
    assert a.outside_window(t0 + 30.0, 0.0, None) is None
    assert a.config.max_behind_s == 30.0 + HISTORY_DEPTH  # a restarted server's history replay
    assert a.outside_window(t0 + (-30.0), 0.0, None) is None  # before the first solve: where
    assert a.outside_window(t0 + (-31.0), 0.0, None) == "too-far-behind"  # the fleet began
    assert a.outside_window(t0 + (-31.0), 0.0, t0 + (-40.0)) is None  # a resume's replay
    assert a.reference(0.0, t0 + 2.0) == t0 + 2.0  # never below the last solved epoch
    # silent vehicles do not count: after silent_after_s only a newcomer is left, alone
    assert a.reference(10.0, None) is None
    lone = bundled.epochs[0]["u1"]
    v = a.check(
        _at(lone, t0 + 600.0, seq=600),
        t0 + 600.0,
        b"n" * 16,
        10.0,
        solved_up_to=t0,
        pending_epochs=0,
        epoch_pending=False,
    )
    assert v.outcome == "admit"  # rejoining after ten minutes (the others quiet for 10 s)
    # ...but a vehicle alone while the fleet pauses cannot jump a week (nor 200 s after 1 s)
    kw: dict[str, Any] = {"solved_up_to": t0, "pending_epochs": 0, "epoch_pending": False}
    week = a.check(_at(lone, t0 + WEEK_S, seq=601), t0 + WEEK_S, b"w" * 16, 10.0, **kw)
    assert (week.outcome, week.reason) == ("reject", "too-far-ahead")
    b = Admission(AdmissionConfig(interval_s=1.0))
    b.admitted("u2", t0, 0, b"2" * 16, 0.0)
    b.offline("u2")  # gone, but heard a second ago
    soon = b.check(_at(lone, t0 + 200.0, seq=200), t0 + 200.0, b"s" * 16, 1.0, **kw)
    assert (soon.outcome, soon.reason) == ("reject", "too-far-ahead")
    alone = Admission(AdmissionConfig(interval_s=1.0))  # nobody else ever heard: a 1-vehicle fleet
    assert alone.check(_at(lone, t0 + WEEK_S, seq=1), t0 + WEEK_S, b"1" * 16, 0.0, **kw).outcome == "admit"


def test_resumed_server_admits_the_history_replay(bundled: Genuine) -> None:
    """After a resume (solved_up_to set, no vehicle state) the caches replay the epochs missed:
    the first vehicle sets the reference, all are admitted and solved."""
    s = _server(bundled)
    s.solved_up_to = gps_time(bundled.epochs[99]["u1"].epoch)
    sols = _feed_lockstep(s, bundled, range(100 - 10, 200), now=5.0)
    assert [sol.epoch for sol in sols] == [b.epoch for b in bundled.solutions[100:200]]
    assert sum(s.rejected_by_reason.values()) == 0


# -- rate -------------------------------------------------------------------------------------------
def test_rate_limit_per_vehicle(bundled: Genuine) -> None:
    """A burst beyond `rate_limit_burst` is rejected (and logged rate-limited); tokens come back per
    wall second and per solved epoch; other vehicles are not affected."""
    s = _server(bundled, rate_limit_burst=10, rate_limit_per_s=2.0, rate_limit_per_epoch=3.0)
    m = bundled.epochs[0]["u1"]
    for _ in range(15):
        _put(s, m, 0.0)
    assert s.rejected_by_reason == {"rate-limited": 5} and s.counters["u1"]["duplicate"] == 9
    _put(s, m, 1.0)  # two tokens back after a second
    _put(s, m, 1.0)
    _put(s, m, 1.0)
    assert s.rejected_by_reason == {"rate-limited": 6}
    _put(s, bundled.epochs[0]["u2"], 1.0)  # another vehicle has its own bucket
    assert "u2" in s.pending[gps_time(m.epoch)]
    s.solve(gps_time(m.epoch))  # a solved epoch gives each vehicle rate_limit_per_epoch tokens
    for _ in range(3):
        _put(s, bundled.epochs[1]["u1"], 1.0)
    assert s.rejected_by_reason == {"rate-limited": 6}
    _invariant(s)


def test_rejections_are_logged_rate_limited(bundled: Genuine, caplog: pytest.LogCaptureFixture) -> None:
    s = _server(bundled, reject_log_every_s=3600.0)
    m = bundled.epochs[3]["u1"]
    with caplog.at_level(logging.WARNING, logger="coplane.fusion_server"):
        for k in range(1000):
            _put(s, _at(m, gps_time(m.epoch) + 0.5 + k), float(k))
            s.handle_node(s.keys.node("u2"), b"{not json", now=float(k))
            s.handle_node(s.keys.node("intruder"), b"{}", now=float(k))
    warnings = [r for r in caplog.records if r.levelno >= logging.WARNING]
    assert len(warnings) == 3  # one per (vehicle, reason)
    assert s.rejected_by_reason == {"off-grid": 1000, "invalid-json": 1000, "unknown-vehicle": 1000}
    assert s.reject_log.suppressed == 2997


# -- plausibility --------------------------------------------------------------------------------
def _with_plane(m: NodeMessage, d: float, sigma: float) -> NodeMessage:
    p = np.asarray(m.spp.position_ecef_m)
    n = p / np.linalg.norm(p)
    plane = PlaneReport(
        status="available", normal=tuple(n), d_antenna_m=d, sigma_m=sigma, centroid_ecef_m=tuple(p)
    )
    return m.model_copy(update={"plane": plane})


def test_absurd_plane_is_kept_out(bundled: Genuine) -> None:
    """d_antenna_m = 1e4 with sigma 0.01 (moved a vehicle by 4,000 km): the message is rejected by
    default; with plane_policy = drop the message is used without the plane."""
    m = next(ep["u2"] for ep in bundled.epochs[5:] if ep["u2"].spp.ok)
    t = gps_time(m.epoch)
    bad = _with_plane(m, 1e4, 0.01)
    assert plane_problem(bad, 30.0, 150.0) is not None
    # a plane off by 1 km, or tilted 45 degrees, with a plausible offset
    p = np.asarray(m.spp.position_ecef_m)
    assert "from the plane" in str(
        plane_problem(_with_plane(m, -float(np.linalg.norm(p)) + 1e3, 0.01), 30.0, 150.0)
    )
    tilted = _with_plane(m, -float(np.linalg.norm(p)), 0.01)
    assert tilted.plane is not None and tilted.plane.normal is not None
    n = np.asarray(tilted.plane.normal)
    e = np.cross([0.0, 0.0, 1.0], n)
    n2 = (n + e / np.linalg.norm(e)) / np.linalg.norm(n + e / np.linalg.norm(e))
    tilted = tilted.model_copy(
        update={"plane": tilted.plane.model_copy(update={"normal": tuple(n2), "d_antenna_m": -float(n2 @ p)})}
    )
    assert plane_problem(tilted, 30.0, 150.0) is not None  # through the fix, but 45 degrees off

    s = _server(bundled)
    s.solved_up_to = t + (-1.0)
    _put(s, bad, 0.0)
    assert s.rejected_by_reason == {"implausible-plane": 1} and not s.pending
    d = _server(bundled, plane_policy="drop")
    d.solved_up_to = t + (-1.0)
    _put(d, bad, 0.0)
    kept = d.pending[t]["u2"]
    assert kept.plane is not None and kept.plane.status == "unavailable" and kept.satellites == m.satellites
    sol = d.solve(t)
    assert sol is not None and abs(np.linalg.norm(sol.vehicles[0].position_ecef_m) - np.linalg.norm(p)) < 1e3


def test_displaced_fix_and_off_earth_fix_are_rejected(bundled: Genuine) -> None:
    m = next(ep["u3"] for ep in bundled.epochs[5:] if ep["u3"].spp.ok)
    t = gps_time(m.epoch)
    p = np.asarray(m.spp.position_ecef_m)
    east = np.cross([0.0, 0.0, 1.0], p)
    east /= np.linalg.norm(east)

    def moved(v: np.ndarray) -> NodeMessage:
        spp = SppReport.model_validate(m.spp.model_copy(update={"position_ecef_m": tuple(v)}).model_dump())
        return m.model_copy(update={"spp": spp})

    s = _server(bundled)
    s.solved_up_to = t + (-1.0)
    _put(s, moved(p + 1000.0 * east), 0.0)  # 1 km along the ground
    _put(s, moved(p * (1.0 + 20_000.0 / np.linalg.norm(p))), 0.0)  # 20 km up
    assert s.rejected_by_reason == {"implausible-spp": 2} and not s.pending
    _put(s, m, 0.0)  # the genuine one still gets in
    assert s.pending[t]["u3"] == m


# -- duplicates and replays ------------------------------------------------------------------------
def test_identical_resend_is_a_duplicate(bundled: Genuine) -> None:
    s = _server(bundled)
    m = bundled.epochs[0]["u1"]
    for _ in range(5):  # a lockstep agent resends every second until it sees the solution
        _put(s, m, 0.0)
    assert s.counters["u1"]["duplicate"] == 4 and s.rejected_by_reason == {}
    assert s.pending[gps_time(m.epoch)]["u1"] == m
    _invariant(s)


def test_conflicting_message_never_displaces_the_first(bundled: Genuine) -> None:
    """A different message for a pending (vehicle, epoch), even a consistent one, is a conflict:
    counted and rejected, the first stays."""
    s = _server(bundled)
    m = bundled.epochs[0]["u2"]
    _put(s, m, 0.0)
    other = m.model_copy(update={"ranges": [], "sent_unix_s": 1.0})
    _put(s, other, 0.0)
    assert s.rejected_by_reason == {"conflict": 1}
    assert s.pending[gps_time(m.epoch)]["u2"] == m
    _invariant(s)


def test_replayed_seq_is_rejected_until_the_agent_restarts(bundled: Genuine) -> None:
    """seq must move with the epoch; an agent that restarts counts from 0 again (seen as seq 0 on a
    later epoch, or as its liveliness token going away)."""
    s = _server(bundled)
    _feed_lockstep(s, bundled, range(10))
    m = bundled.epochs[10]["u1"]
    t = gps_time(m.epoch)
    assert m.seq == 10
    _put(s, _at(m, t + 1.0, seq=5), 0.2)  # an old seq on a new epoch
    _put(s, _at(m, t + 1.0, seq=10_000), 0.2)  # a seq jump past the epochs
    assert s.rejected_by_reason == {"replay": 2}
    _put(s, m, 0.2)
    assert s.pending[t]["u1"] == m
    _put(s, _at(m, t + 1.0, seq=0), 0.3)  # restarted before its old token expired
    _put(s, _at(m, t + 2.0, seq=1), 0.3)
    _put(s, _at(m, t + 3.0, seq=1), 0.3)  # the same seq on the next epoch: a replay
    assert s.rejected_by_reason == {"replay": 3} and {t + 1.0, t + 2.0} <= set(s.pending)
    # the token goes away and comes back: whatever seq it starts from is taken
    s.handle_alive(s.keys.alive("agent", "u1"), False)
    s.handle_alive(s.keys.alive("agent", "u1"), True)
    _put(s, _at(m, t + 4.0, seq=7), 0.4)
    assert s.rejected_by_reason == {"replay": 3} and t + 4.0 in s.pending
    _invariant(s)


# -- liveliness ------------------------------------------------------------------------------------
def test_fake_liveliness_token_stalls_lockstep_once(bundled: Genuine) -> None:
    """A token without an agent (u4 here): lockstep waits stall_timeout_s once, then solves without
    it every epoch, until it sends an admitted message."""
    s = _server(bundled, stall_timeout_s=5.0)
    now = 0.0
    waits = []
    for k in range(10):
        for vid in ("u1", "u2", "u3"):
            _put(s, bundled.epochs[k][vid], now)
        start = now
        while not _solve_ready(s, now):
            now += 0.5
        waits.append(now - start)
        now += 0.01
    assert waits[0] > 5.0 and all(w == 0.0 for w in waits[1:]), waits
    assert s.admission.is_silent("u4")
    _put(s, bundled.epochs[10]["u4"], now)  # it speaks: waited for again
    assert not s.admission.is_silent("u4")
