"""Direct tests of `coplane.replay`: the replay schedule and builder shared by `coplane eval` and the bus.

Small synthetic inputs for the pure functions; the bundled recording (4 vehicles, 600 epochs at
1 s, with a base station and UWB) for the functions that read a recording.
"""

from __future__ import annotations

import dataclasses
import itertools
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st
from support.fresh_python import fresh_python

from coplane.errors import ConfigError, NotFoundError
from coplane.gnss.dgnss import DgnssCorrections
from coplane.gtime import SECONDS_PER_WEEK, GpsTime
from coplane.ids import VEHICLE_ID
from coplane.methods import get_method
from coplane.plane.config import PlaneConfig
from coplane.recording.model import Manifest, ObsEpoch, SatObservation, UwbRange, UwbSpec, VehicleSpec
from coplane.recording.reader import Recording, open_recording
from coplane.recording.writer import write_obs
from coplane.replay import (
    DEFAULT_UWB_SIGMA_M,
    BaseCorrections,
    ReplaySetup,
    base_by_epoch,
    first_epoch,
    fleet_id,
    nominal_grid,
    replay_setup,
    uwb_for_vehicle,
    vehicle_schedule,
)
from coplane.sim.generate import bundled_default_path
from coplane.steps import FusionStep, VehicleStep

W = 2320
T0 = GpsTime(W, 115800.0)


@pytest.fixture(scope="module")
def rec() -> Recording:
    """The bundled default recording (read lazily; each test loads only what it needs)."""
    return open_recording(bundled_default_path())


def ep(tow: float, week: int = W) -> ObsEpoch:
    return ObsEpoch(GpsTime(week, tow), (SatObservation("G01", 2.2e7),))


def no_base(manifest: Manifest, **kw: object) -> Manifest:
    return dataclasses.replace(manifest, base=None, **kw)  # type: ignore[arg-type]


# -- nominal_grid -------------------------------------------------------------------------------


def test_nominal_grid_rounds_receiver_tags() -> None:
    """Receiver tags a few ms off the second give the whole seconds between them, both ends included."""
    grid = list(nominal_grid(GpsTime(W, 100.004), GpsTime(W, 102.996), 1.0))
    assert grid == [GpsTime(W, 100.0), GpsTime(W, 101.0), GpsTime(W, 102.0), GpsTime(W, 103.0)]


def test_nominal_grid_single_epoch() -> None:
    """First equal to last gives one nominal epoch."""
    assert list(nominal_grid(GpsTime(W, 5.2), GpsTime(W, 5.2), 1.0)) == [GpsTime(W, 5.0)]


def test_nominal_grid_across_week_rollover() -> None:
    """The grid continues across the end of a GPS week without a gap or a duplicate."""
    grid = list(nominal_grid(GpsTime(W, SECONDS_PER_WEEK - 2.0), GpsTime(W + 1, 1.0), 1.0))
    assert grid == [
        GpsTime(W, SECONDS_PER_WEEK - 2.0),
        GpsTime(W, SECONDS_PER_WEEK - 1.0),
        GpsTime(W + 1, 0.0),
        GpsTime(W + 1, 1.0),
    ]


@pytest.mark.parametrize("dt", [0.1, 0.2, 0.5, 2.0, 5.0])
def test_nominal_grid_points_are_fixed_points_of_round_to(dt: float) -> None:
    """Every grid time is its own nominal time (so dict lookups by round_to hit), spaced by the interval."""
    first, last = GpsTime(W, 115800.03), GpsTime(W, 115830.0)
    grid = list(nominal_grid(first, last, dt))
    assert len(grid) == round((last.round_to(dt) - first.round_to(dt)) / dt) + 1
    assert all(t.round_to(dt) == t for t in grid)
    assert all(abs((b - a) - dt) < 1e-6 for a, b in itertools.pairwise(grid))
    assert len(set(grid)) == len(grid)


# -- vehicle_schedule ---------------------------------------------------------------------------


def test_schedule_empty() -> None:
    """A vehicle without epochs has no schedule (it is never live)."""
    assert vehicle_schedule([], 1.0) == []


def test_schedule_fills_gaps_with_none() -> None:
    """A nominal epoch without a receiver epoch (an underpass) is in the schedule with None."""
    e0, e1, e3 = ep(100.004), ep(101.003), ep(103.0)
    assert vehicle_schedule([e0, e1, e3], 1.0) == [
        (GpsTime(W, 100.0), e0),
        (GpsTime(W, 101.0), e1),
        (GpsTime(W, 102.0), None),
        (GpsTime(W, 103.0), e3),
    ]


def test_schedule_first_epoch_wins_a_nominal_time() -> None:
    """Two receiver epochs rounding to one nominal time: the first is kept."""
    a, b = ep(100.0), ep(100.2)
    assert vehicle_schedule([a, b, ep(101.0)], 1.0)[0] == (GpsTime(W, 100.0), a)


def test_schedule_spans_first_to_last_only() -> None:
    """The schedule starts at the vehicle's first epoch and ends at its last (live span only)."""
    sched = vehicle_schedule([ep(200.0), ep(203.0)], 1.0)
    assert [t for t, _ in sched] == [GpsTime(W, 200.0 + k) for k in range(4)]
    assert [e is None for _, e in sched] == [False, True, True, False]


def test_schedule_of_bundled_vehicle(rec: Recording) -> None:
    """Every vehicle of the bundled recording is live at all 600 nominal epochs, each with its receiver epoch."""
    epochs = rec.vehicle_epochs("u2")
    sched = vehicle_schedule(epochs, rec.interval_s)
    assert len(sched) == 600
    assert sched[0][0] == T0 and sched[-1][0] == T0 + 599.0
    assert all(e is not None and e.time.round_to(1.0) == t for t, e in sched)
    assert [e for _, e in sched] == epochs


# -- fleet_id -----------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("name", "expected"),
    [
        ("sim urban-loop seed 0: 4 vehicles, 600 epochs", "sim-urban-loop-seed-0-4-vehicles"),
        ("Hong Kong / TST  2021", "Hong-Kong-TST-2021"),
        ("keep_under_scores", "keep_under_scores"),
        ("--edge--", "edge"),
        ("a" * 31 + " b", "a" * 31),  # cut at 32, then the trailing dash stripped
        ("", "fleet"),
        ("   ", "fleet"),
        ("!!! ???", "fleet"),
    ],
)
def test_fleet_id_examples(name: str, expected: str) -> None:
    """A recording's free-text name becomes a dash-separated slug, 'fleet' when nothing is left."""
    assert fleet_id(name) == expected


@given(st.text(alphabet=st.characters(max_codepoint=127), max_size=80))
def test_fleet_id_of_ascii_is_a_vehicle_id(name: str) -> None:
    """Any ASCII name gives a bus-safe id (VEHICLE_ID: 1..32 of [A-Za-z0-9_-]) without doubled or edge dashes."""
    fid = fleet_id(name)
    assert VEHICLE_ID.fullmatch(fid)
    assert "--" not in fid and not fid.startswith("-") and not fid.endswith("-")


@pytest.mark.parametrize("name", ["Zürich loop", "run ²", "東京"])
def test_fleet_id_of_non_ascii_is_a_vehicle_id(name: str) -> None:
    """A name with non-ASCII letters or digits also gives a bus-safe fleet id."""
    assert VEHICLE_ID.fullmatch(fleet_id(name))


# -- uwb_for_vehicle ----------------------------------------------------------------------------


def rng(tow: float, a: str, b: str, r: float = 10.0) -> UwbRange:
    return UwbRange(GpsTime(W, tow), a, b, r)


def test_uwb_only_rows_the_vehicle_measured() -> None:
    """A vehicle gets the rows where it is `from` (a), never the rows others measured to it."""
    rows = [rng(100.0, "u1", "u2"), rng(100.0, "u2", "u1"), rng(100.0, "u3", "u1"), rng(100.0, "u1", "u3")]
    out = uwb_for_vehicle(rows, "u1", [GpsTime(W, 100.0)], 1.0)
    assert out == {GpsTime(W, 100.0): [rows[0], rows[3]]}


def test_uwb_nearest_epoch_within_tolerance() -> None:
    """A row belongs to the nearest nominal epoch within 0.1 x interval; rows further off are dropped."""
    near, late, early, far = (
        rng(100.05, "u1", "u2"),
        rng(100.96, "u1", "u3"),
        rng(101.92, "u1", "u4"),
        rng(102.4, "u1", "u2"),
    )
    times = [GpsTime(W, 100.0 + k) for k in range(3)]
    out = uwb_for_vehicle([near, late, early, far], "u1", times, 1.0)
    assert out == {GpsTime(W, 100.0): [near], GpsTime(W, 101.0): [late], GpsTime(W, 102.0): [early]}
    # a wider tolerance admits the row 0.4 s off
    assert uwb_for_vehicle([far], "u1", times, 1.0, tolerance=0.45) == {GpsTime(W, 102.0): [far]}


def test_uwb_only_at_the_vehicles_epochs() -> None:
    """Rows at nominal epochs where the vehicle does not report are dropped."""
    rows = [rng(100.0, "u1", "u2"), rng(105.0, "u1", "u2")]
    assert uwb_for_vehicle(rows, "u1", [GpsTime(W, 105.0)], 1.0) == {GpsTime(W, 105.0): [rows[1]]}


def test_uwb_one_row_per_pair_and_epoch() -> None:
    """A pair at most once per epoch: the first row wins, a later one in the same epoch is dropped."""
    first, again, other = rng(100.0, "u1", "u2", 10.0), rng(100.04, "u1", "u2", 11.0), rng(100.0, "u1", "u3")
    out = uwb_for_vehicle([first, again, other], "u1", [GpsTime(W, 100.0)], 1.0)
    assert out == {GpsTime(W, 100.0): [first, other]}


def test_uwb_self_range_dropped() -> None:
    """A row from a vehicle to itself is never returned."""
    assert uwb_for_vehicle([rng(100.0, "u1", "u1")], "u1", [GpsTime(W, 100.0)], 1.0) == {}


def test_uwb_accepts_a_generator_of_times() -> None:
    """`times` may be a one-shot iterator (the evaluator passes a generator)."""
    rows = [rng(100.0, "u1", "u2"), rng(101.0, "u1", "u2")]
    out = uwb_for_vehicle(rows, "u1", (GpsTime(W, 100.0 + k) for k in range(2)), 1.0)
    assert sorted(out) == [GpsTime(W, 100.0), GpsTime(W, 101.0)]


def test_uwb_of_bundled_recording(rec: Recording) -> None:
    """On the bundled recording every row of u1 at a whole second lands at that epoch, at most one per peer."""
    rows = rec.uwb()
    times = [t for t, _ in vehicle_schedule(rec.vehicle_epochs("u1"), 1.0)]
    out = uwb_for_vehicle(rows, "u1", times, 1.0)
    mine = [r for r in rows if r.a == "u1"]
    assert sum(len(v) for v in out.values()) == len(mine) > 0
    for t, rs in out.items():
        assert all(r.time.round_to(1.0) == t for r in rs)
        assert len({r.b for r in rs}) == len(rs)


# -- first_epoch and base_by_epoch --------------------------------------------------------------


def test_first_epoch_of_bundled(rec: Recording) -> None:
    """The bundled recording's first nominal epoch is its first second."""
    assert first_epoch(rec) == T0


def _two_vehicles(tmp_path: Path, rec: Recording, starts: tuple[int | None, int | None]) -> Recording:
    """A recording of u1/u2 whose observation files start at the given bundled epoch (None: empty file)."""
    vehicles = []
    for vid, start in zip(("u1", "u2"), starts, strict=True):
        epochs = rec.vehicle_epochs(vid)[start : start + 3] if start is not None else []
        path = write_obs(tmp_path / f"{vid}.obs", rec.vehicle_header(vid), epochs)
        vehicles.append(VehicleSpec(vid, path, 1.5))
    return Recording(Manifest(tmp_path, "two", 1.0, (), tuple(vehicles)))


def test_first_epoch_is_the_earliest_vehicle(tmp_path: Path, rec: Recording) -> None:
    """The fleet's first epoch is the earliest first epoch of any vehicle, rounded to the interval."""
    r = _two_vehicles(tmp_path, rec, (5, 2))
    assert first_epoch(r) == T0 + 2.0


def test_first_epoch_skips_empty_files(tmp_path: Path, rec: Recording) -> None:
    """A vehicle without epochs does not count; with none at all there is no first epoch."""
    assert first_epoch(_two_vehicles(tmp_path, rec, (None, 4))) == T0 + 4.0
    assert first_epoch(_two_vehicles(tmp_path / "empty", rec, (None, None))) is None


def test_base_by_epoch_of_bundled(rec: Recording) -> None:
    """The base station's epochs keyed by nominal time, one per second of the recording."""
    by_t = base_by_epoch(rec)
    assert len(by_t) == 600
    assert min(by_t) == T0
    assert all(e.time.round_to(1.0) == t for t, e in by_t.items())


def test_base_by_epoch_without_base(tmp_path: Path, rec: Recording) -> None:
    """A recording without [base] has no base epochs."""
    assert base_by_epoch(_two_vehicles(tmp_path, rec, (0, 0))) == {}


# -- replay_setup -------------------------------------------------------------------------------


def test_setup_from_bundled_manifest(rec: Recording) -> None:
    """Defaults: DGNSS on (the recording has a base), fleet id from the name, UWB sigma from the manifest."""
    s = replay_setup(rec.manifest, "pc")
    assert isinstance(s, ReplaySetup)
    assert s.use_dgnss is True
    assert s.fleet == fleet_id(rec.manifest.name) == "sim-urban-loop-seed-0-4-vehicles"
    assert s.method is get_method("pc")
    assert rec.manifest.uwb is not None
    assert s.vehicle_config.uwb_sigma_m == rec.manifest.uwb.sigma_m
    assert s.vehicle_config.seed == 0
    assert s.fusion_config.interruption_rate == 0.0
    assert s.fusion_config.interval_s == rec.manifest.interval_s


def test_setup_passes_options_through(rec: Recording) -> None:
    """Seed, interruption, fleet override, plane config and a MethodSpec object all reach the step configs."""
    spec = get_method("mci")
    pc = PlaneConfig(range_fitting_m=30.0)
    s = replay_setup(
        rec.manifest, spec, seed=7, interruption=0.4, dgnss=False, plane_config=pc, fleet="my-fleet"
    )
    assert s.method is spec and s.fleet == "my-fleet" and s.use_dgnss is False
    assert s.vehicle_config.seed == 7 and s.vehicle_config.plane is pc
    assert (s.fusion_config.interruption_rate, s.fusion_config.interruption_seed) == (0.4, 7)


def test_setup_without_base(rec: Recording) -> None:
    """Without [base], DGNSS is off by default and asking for it is a ConfigError naming the recording."""
    m = no_base(rec.manifest)
    assert replay_setup(m, "pc").use_dgnss is False
    with pytest.raises(ConfigError, match=r"has no \[base\]: cannot run with DGNSS"):
        replay_setup(m, "pc", dgnss=True)


def test_setup_uwb_sigma(rec: Recording) -> None:
    """Without [uwb] the default sigma is used; a manifest's own sigma is taken as is."""
    assert (
        replay_setup(no_base(rec.manifest, uwb=None), "mci").vehicle_config.uwb_sigma_m == DEFAULT_UWB_SIGMA_M
    )
    m = dataclasses.replace(rec.manifest, uwb=UwbSpec(Path("uwb.csv"), sigma_m=0.55))
    assert replay_setup(m, "mci").vehicle_config.uwb_sigma_m == 0.55


def test_setup_unknown_method(rec: Recording) -> None:
    """An unknown method name is a ConfigError listing the valid ones."""
    with pytest.raises(ConfigError, match="unknown method 'nope'"):
        replay_setup(rec.manifest, "nope")


def test_setup_configs_are_fresh(rec: Recording) -> None:
    """Two setups do not share a mutable vehicle config (a plane override on one leaves the other alone)."""
    a = replay_setup(rec.manifest, "pc", plane_config=PlaneConfig(range_fitting_m=30.0))
    b = replay_setup(rec.manifest, "pc")
    assert b.vehicle_config.plane == PlaneConfig() != a.vehicle_config.plane


def test_setup_builds_the_steps(rec: Recording) -> None:
    """vehicle_step uses the manifest's antenna height and the setup's fleet/method/config; fusion_step likewise."""
    s = replay_setup(rec.manifest, "pc", seed=3, interruption=0.2)
    v = s.vehicle_step(rec, "u3")
    assert isinstance(v, VehicleStep)
    assert (v.fleet, v.vehicle_id, v.method, v.config) == (s.fleet, "u3", s.method, s.vehicle_config)
    assert v.antenna_height_m == rec.manifest.vehicle("u3").antenna_height_m == 1.777
    assert v.nav is rec.nav
    f = s.fusion_step()
    assert isinstance(f, FusionStep)
    assert (f.fleet, f.method, f.config, f.seq) == (s.fleet, s.method, s.fusion_config, 0)
    assert s.fusion_step() is not f  # a fresh estimator each time
    with pytest.raises(NotFoundError, match="vehicle 'u9'"):
        s.vehicle_step(rec, "u9")


# -- BaseCorrections ----------------------------------------------------------------------------


def test_base_corrections_off(rec: Recording) -> None:
    """Without DGNSS no base file is read and every epoch has no corrections."""
    b = BaseCorrections.of(rec, use_dgnss=False)
    assert b.by_t == {} and b.position is None
    assert b.at(T0) is None


def test_base_corrections_without_base_in_manifest(tmp_path: Path, rec: Recording) -> None:
    """Asking for DGNSS on a recording without [base] gives no corrections (not an error here)."""
    b = BaseCorrections.of(_two_vehicles(tmp_path, rec, (0, 0)), use_dgnss=True)
    assert b.by_t == {} and b.at(T0) is None


def test_base_corrections_on(rec: Recording) -> None:
    """With DGNSS, an epoch with a base observation has per-satellite corrections; it is computed once."""
    b = BaseCorrections.of(rec, use_dgnss=True)
    assert b.position is not None and len(b.by_t) == 600
    c = b.at(T0 + 10.0)
    assert isinstance(c, DgnssCorrections)
    assert c.time.round_to(1.0) == T0 + 10.0
    assert len(c.corrections_m) >= 4
    assert b.at(T0 + 10.0) is c  # the cached one for the same epoch
    c2 = b.at(T0 + 11.0)
    assert c2 is not None and c2 is not c and c2.time.round_to(1.0) == T0 + 11.0


def test_base_corrections_outside_base_span(rec: Recording) -> None:
    """A nominal epoch the base did not observe has no corrections (and is cached as such)."""
    b = BaseCorrections.of(rec, use_dgnss=True)
    assert b.at(T0 + -100.0) is None
    assert b.at(T0 + 5.0) is not None


# -- layering -----------------------------------------------------------------------------------


def test_import_does_not_load_estimators() -> None:
    """Importing coplane.replay (as the API does for fleet_id) loads neither the steps, the estimators nor GTSAM."""
    code = (
        "import sys, coplane.replay\n"
        "bad = sorted(m for m in sys.modules if m.split('.')[0] == 'gtsam' or m.startswith("
        "('coplane.steps', 'coplane.fgo', 'coplane.baselines', 'coplane.methods')))\n"
        "print(','.join(bad))\n"
    )
    assert fresh_python(code) == ""
