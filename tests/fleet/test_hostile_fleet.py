"""Valid-but-hostile input through a live fleet (issue 13, acceptance): nothing moves a genuine vehicle.

A compromised vehicle (the recording's last one: its certificate is the attacker's, its genuine
agent is not run) sends 1000 Hypothesis-built hostile node messages (tests/support/hostile.py: future,
past, off-grid, replayed, duplicate, conflicting, absurd planes, displaced fixes, oversized), some
of them before the fleet has started, and 1000 forged solutions on the solution key. The genuine
vehicles' positions must equal the clean run's (the in-process lockstep replay of the genuine
vehicles, which a clean lockstep run over the bus equals bit for bit): `array_equal` in lockstep,
every epoch solved and within 1 mm at the realtime pace; no process crashes; `pending` stays
within its bound in every diagnostics message. On the secure bus the router drops the forged
solutions; on an insecure bus they reach every consumer, whose gate must drop them.
docs/reliability/hostile-input.md (bench/reliability_hostile.py) has the same runs, larger.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from support.hostile import (
    NODE_KINDS,
    SOLUTION_KINDS,
    AttackRun,
    Genuine,
    balanced,
    clean_reference,
    draw_all,
    genuine_material,
    max_position_diff,
    node_attacks,
    run_attack,
    solution_attacks,
)

from coplane.fleet import fleet_of
from coplane.sim.generate import simulate

pytestmark = pytest.mark.slow
DURATION_S = 20
# the lockstep attack's own recording: its rounds follow the fleet's solved epochs, and 20 epochs
# are solved in about the time the attack takes to send (overlap 0.36-0.82 on one 2-core host);
# 60 give the attack the fleet's time to land in
LOCKSTEP_DURATION_S = 60
N_NODE = 1000
N_SOLUTIONS = 1000


class Material:
    def __init__(self, root: Path, duration_s: float = DURATION_S) -> None:
        self.recording = simulate("urban-loop", root / "r", vehicles=4, duration_s=duration_s, seed=3)
        _, vehicles = fleet_of(self.recording)
        self.attacker = vehicles[-1]
        self.genuine_ids = vehicles[:-1]
        self.genuine: Genuine = genuine_material(self.recording, "pc")
        self.reference = clean_reference(self.recording, "pc", self.genuine_ids)
        self.nodes = balanced(node_attacks, NODE_KINDS, N_NODE)
        self.solutions = balanced(solution_attacks, SOLUTION_KINDS, N_SOLUTIONS)
        # before the fleet starts: epochs ahead, the freeze of issue 13 if nothing else is known yet
        self.early = draw_all(node_attacks(["future", "off-grid", "displaced-fix"]), 6)


@pytest.fixture(scope="module")
def material(tmp_path_factory: pytest.TempPathFactory) -> Material:
    return Material(tmp_path_factory.mktemp("hostile"))


@pytest.fixture(scope="module")
def lockstep_material(tmp_path_factory: pytest.TempPathFactory) -> Material:
    return Material(tmp_path_factory.mktemp("hostile-lockstep"), LOCKSTEP_DURATION_S)


def _genuine_positions(m: Material, r: AttackRun) -> dict:
    return {v: p for v, p in r.positions.items() if v in m.reference}


def _check_common(m: Material, r: AttackRun) -> None:
    """No crash, pending bounded, every genuine message used, every hostile one accounted for."""
    print(
        f"{r.label}: sent {r.log.node_sent.total()} node ({r.log.node_bytes / 1e6:.0f} MB), "
        f"{r.log.solutions_sent.total()} solutions in {r.send_s:.1f} s ({r.attack_overlap:.0%} before the "
        f"genuine run ended); wall {r.wall_s:.0f} s; "
        f"pending max {r.pending_max} / {r.pending_limit}; reasons {r.diag.rejected_by_reason if r.diag else None}"
    )
    assert not r.crashed, r.crashed
    assert not r.timed_out, r.timed_out
    assert r.log.send_errors == 0
    assert r.log.node_sent.total() == N_NODE + len(m.early)
    assert r.log.solutions_sent.total() == N_SOLUTIONS
    assert r.n_diagnostics >= 3
    assert r.pending_limit > 0 and r.pending_max <= r.pending_limit
    d = r.diag
    assert d is not None
    for vid in m.genuine_ids:  # the genuine vehicles: every message used, none rejected or late
        c = d.vehicles[vid]
        assert c.rejected == 0 and c.late == 0, (vid, c)
        assert c.used == len(m.reference[vid]), (vid, c)
    c = d.vehicles[m.attacker]
    assert c.received == c.used + c.rejected + c.late + c.duplicate, c
    # everything the attacker put arrived (reliable, BLOCK) except what Zenoh drops in transit
    assert r.log.node_sent.total() - r.log.node_over_transport <= c.received <= r.log.node_sent.total()
    # the attacker's plane never reaches the estimator; it is solved only after the genuine
    # vehicles' last epoch (alone: it never joins a genuine epoch), and never a week ahead (once the
    # genuine vehicles are quiet the server lets a lone vehicle rejoin at up to 100 epoch seconds
    # per wall second: docs/bus.md, Admission)
    assert not any(r.attacker_plane_used.values())
    end = max(m.genuine.epochs)
    assert all(0 < t - end <= 3600.0 for t in r.attacker_positions), sorted(r.attacker_positions)


def test_compromised_vehicle_lockstep_changes_no_genuine_bit(
    lockstep_material: Material, tmp_path: Path
) -> None:
    m = lockstep_material
    r = run_attack(
        m.recording,
        "pc",
        m.attacker,
        m.genuine,
        m.nodes,
        m.solutions,
        pace="lockstep",
        early_specs=m.early,
        log_dir=tmp_path / "logs",
        follow_fleet=True,
    )
    _check_common(m, r)
    worst, n, problems = max_position_diff(m.reference, _genuine_positions(m, r))
    assert not problems, problems
    assert n == sum(len(p) for p in m.reference.values())
    for vid, pos in m.reference.items():  # bit for bit
        assert all(np.array_equal(r.positions[vid][t], p) for t, p in pos.items()), vid
    assert worst == 0.0
    # secure bus: the router drops every forged solution, consumers only see the server's
    assert r.forged_seen == 0
    # the attack ran while the genuine fleet did: its rounds follow the fleet's solved epochs (paced
    # on the wall clock alone, a fast host solved 20 epochs while only 0.23 of it was sent)
    assert r.attack_overlap > 0.5


@pytest.mark.serial
def test_compromised_vehicle_realtime_no_stall(material: Material, tmp_path: Path) -> None:
    m = material
    r = run_attack(
        m.recording,
        "pc",
        m.attacker,
        m.genuine,
        m.nodes,
        m.solutions,
        pace="realtime",
        # 1x: an agent more than one interval behind skips the epoch, and at 2x (0.5 s) a loaded
        # 2-core CI runner made one agent skip one (19 of 20) in two runs out of about ten
        speed=1.0,
        # the agents' shared start: a realtime agent that starts after it skips the epochs already
        # past (it joins at the current one), and five processes importing GTSAM on a loaded
        # 2-core CI runner took more than 8 s once (u1 published 19 of 20 epochs); run_attack makes
        # the server wait for the fleet until 5 s after this start
        start_delay_s=15.0,
        per_round=50,
        round_s=0.25,
        early_specs=m.early,
        log_dir=tmp_path / "logs",
    )
    _check_common(m, r)
    worst, _, problems = max_position_diff(m.reference, _genuine_positions(m, r))
    # 0 stalls: every epoch the genuine agents published is solved, with every genuine vehicle
    assert not problems, problems
    assert worst <= 1e-3, worst
    assert r.forged_seen == 0


def test_forged_solutions_on_an_insecure_bus_reach_no_result(material: Material, tmp_path: Path) -> None:
    """Insecure bus: the forged solutions reach the consumers (collector, agents) and their gate
    drops them; the attacker sends only on the compromised vehicle's key (on the genuine
    vehicles' keys it could send a conflicting message before the genuine one: that is what the
    secure bus is for)."""
    m = material
    r = run_attack(
        m.recording,
        "pc",
        m.attacker,
        m.genuine,
        m.nodes,
        balanced(solution_attacks, SOLUTION_KINDS, N_SOLUTIONS),
        pace="lockstep",
        secure=False,
        log_dir=tmp_path / "logs",
    )
    assert not r.crashed, r.crashed
    assert not r.timed_out, r.timed_out
    assert r.log.solutions_sent.total() == N_SOLUTIONS
    # the forged solutions did reach the consumers
    assert r.forged_seen == N_SOLUTIONS
    worst, _, problems = max_position_diff(m.reference, _genuine_positions(m, r))
    print(f"collector gate: {dict(r.untrusted)}; max diff {worst:.1e} m; {problems}")
    assert not problems, problems
    assert worst == 0.0
    assert sum(r.untrusted.values()) >= N_SOLUTIONS * 0.99
