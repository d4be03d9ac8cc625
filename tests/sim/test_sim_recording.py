"""Simulated recordings: spec layout, zero reader problems, RTKLIB reads them, determinism, physics
consistency (no injected error -> exact SPP), the underpass gap, the CLI and the bundled default."""

from __future__ import annotations

import dataclasses as dc
import hashlib
import re
from pathlib import Path

import numpy as np
import pytest
from support import rtklib_ref as rr
from typer.testing import CliRunner

from coplane.errors import ConfigError
from coplane.evaluate.metrics import enu_errors
from coplane.evaluate.spp_run import run_spp
from coplane.gnss.epoch_solver import EpochSolverOptions
from coplane.gnss.spp import SppOptions
from coplane.recording.output_dir import MARKER
from coplane.recording.reader import open_recording
from coplane.sim import errors as er
from coplane.sim.canyon import BLOCKED
from coplane.sim.diagnostics import NOT_VISIBLE
from coplane.sim.generate import (
    DEFAULT_RECORDING,
    bundled_default_path,
    ensure_default_recording,
    run_simulation,
    simulate,
)
from coplane.sim.scenarios import SCENARIOS, get_scenario
from coplane.sim.write import write_recording


def _digest(root: Path) -> dict[str, str]:
    """The recording's files (not the hidden mark of the command that wrote the folder)."""
    return {
        p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(root.rglob("*"))
        if p.is_file() and p.name != MARKER
    }


@pytest.fixture(scope="module", params=sorted(SCENARIOS))
def recording(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Each scenario, 3 vehicles x 90 s."""
    out = tmp_path_factory.mktemp(request.param)
    return simulate(request.param, out, vehicles=3, duration_s=90.0, seed=11)


def test_layout_and_zero_reader_problems(recording: Path) -> None:
    rec = open_recording(recording)
    epochs = list(rec.fleet_epochs())
    ids = [v.id for v in rec.manifest.vehicles]
    for vid in ids:
        assert len(rec.truth_at(vid)) == 90  # every truth row matches an epoch
        assert len(rec.vehicle_epochs(vid)) == 90
    assert len(rec.base_epochs()) == 90
    assert len(rec.uwb()) > 0
    assert len(epochs) == 90
    assert all(fe.base is not None and len(fe.vehicles) == 3 for fe in epochs)
    assert rec.problems.total == 0, rec.problems.items[:5]
    for sub in ("fleet.toml", "nav/brdc.rnx", "base/ref.obs", "uwb.csv", "vehicles/u1.obs", "truth/u1.csv"):
        assert (recording / sub).is_file()
    # tags are receiver time: vehicles a few ms off the whole second, the steered base on it
    offs = [abs(e.time - fe.time) for fe in epochs for e in fe.vehicles.values()]
    assert 0.0 < max(offs) < 0.01
    assert max(abs(fe.base.time - fe.time) for fe in epochs if fe.base is not None) < 1e-6
    header = (recording / "truth/u1.csv").read_text().splitlines()[0]
    assert header.split(",")[:5] == ["gps_week", "tow_s", "x_m", "y_m", "z_m"] and "section" in header


def test_rtklib_reads_the_rinex_files(recording: Path) -> None:
    rec = open_recording(recording)
    nav = rr.load_nav(recording / "nav" / "brdc.rnx")
    assert nav.n >= 45  # GPS + BeiDou (+ the file's other systems)
    for name, ours in [("base/ref.obs", rec.base_epochs())] + [
        (f"vehicles/{v.id}.obs", rec.vehicle_epochs(v.id)) for v in rec.manifest.vehicles
    ]:
        obs = rr.load_obs(recording / name)
        eps = rr.split_epochs(obs)
        nonempty = [e for e in ours if e.sats]  # RTKLIB keeps no record of an empty epoch
        assert len(eps) == len(nonempty), name
        assert obs.n == sum(len(e.sats) for e in ours), name
        for a, b in zip(eps[:5], nonempty[:5], strict=True):
            assert abs(a.time - b.time) < 1e-6
            pr = rr.epoch_pseudoranges(a)
            assert pr == pytest.approx({s.sat: s.pseudorange_m for s in b.sats}, abs=1e-3)


def test_same_seed_same_bytes_different_seed_different(tmp_path: Path) -> None:
    a = _digest(simulate("urban-loop", tmp_path / "a", vehicles=3, duration_s=40.0, seed=5))
    b = _digest(simulate("urban-loop", tmp_path / "b", vehicles=3, duration_s=40.0, seed=5))
    c = _digest(simulate("urban-loop", tmp_path / "c", vehicles=3, duration_s=40.0, seed=6))
    assert a == b
    assert a["nav/brdc.rnx"] == c["nav/brdc.rnx"]
    assert all(a[k] != c[k] for k in a if k != "nav/brdc.rnx")


def _error_free(name: str) -> er.ReceiverParams:
    base = er.base_receiver_params() if name == "base" else er.ReceiverParams()
    return dc.replace(
        base,
        multipath=dc.replace(base.multipath, scale=0.0),
        tracking=dc.replace(base.tracking, dll_bandwidth_hz=0.0, doppler_sigma_hz_at_45=0.0),
    )


def test_without_injected_errors_spp_recovers_truth_exactly(tmp_path: Path) -> None:
    """No orbit/iono/tropo/multipath/noise error: the project's SPP (broadcast clocks, TGD, Klobuchar,
    Saastamoinen, Sagnac) must land on the truth to the RINEX 1 mm resolution, and the Doppler
    velocity on the truth velocity. This pins emission time, Sagnac, TGD and the Doppler sign."""
    sc = dc.replace(
        get_scenario("open-sky"),
        common_mode=er.CommonModeParams(sigma_m={"G": 0.0, "C": 0.0}, bds_geo_sigma_m=0.0, drift_sigma_m=0.0),
        iono=er.IonoParams(scale_sigma=0.0, coeff_sigma=0.0, sat_sigma_m=0.0),
        tropo=er.TropoParams(scale_sigma=0.0, wet_residual_sigma_m=0.0),
        vehicle_receiver=_error_free("vehicle"),
        base_receiver=_error_free("base"),
    )
    res = run_simulation(sc, 2, 40.0, seed=2)
    rec = open_recording(write_recording(res, tmp_path / "zero"))
    opts = EpochSolverOptions(spp=SppOptions(raim="off"))
    for dgnss, tol in ((False, 0.005), (True, 0.03)):
        for vid, run in run_spp(rec, dgnss=dgnss, options=opts).items():
            truth = {t: np.asarray(p) for t, p in rec.truth_at(vid).items()}
            _, e = enu_errors(run.fixes(), truth)
            assert len(e) == 40
            print(f"error-free {vid} dgnss={dgnss}: max |ENU error| {np.abs(e).max():.4f} m")
            assert np.abs(e).max() < tol
            if not dgnss:
                v = np.array(
                    [r.velocity.velocity_mps for r in run.results.values() if r.velocity is not None]
                )
                k = res.vehicle_ids.index(vid)
                dv = np.linalg.norm(v - res.track.vel_ecef[:, k], axis=1)
                print(f"error-free {vid}: max |velocity error| {dv.max():.4f} m/s")
                assert dv.max() < 0.01


def test_underpass_blocks_gnss_for_8_to_15_seconds() -> None:
    res = run_simulation("urban-loop", 4, 330.0, seed=0, diagnostics=True)
    d = res.diagnostics
    assert d is not None
    m = len(res.vehicle_ids)
    st = d.state[:, :m]
    all_blocked = np.all((st == BLOCKED) | (st == NOT_VISIBLE), axis=2)
    under = res.track.section_names()[:, :m] == "underpass"
    for v in range(m):
        runs, n = [], 0
        for flag in all_blocked[:, v]:
            if flag:
                n += 1
            elif n:
                runs.append(n)
                n = 0
        print(
            f"{res.vehicle_ids[v]}: GNSS fully blocked for {runs} s; under the deck {int(under[:, v].sum())} s"
        )
        assert len(runs) == 1 and 8 <= runs[0] <= 15
        assert not np.any(d.reported[:, v][all_blocked[:, v]])
        assert np.all(all_blocked[:, v][under[:, v]])


def test_cli_writes_a_recording(tmp_path: Path) -> None:
    from coplane.cli import app

    out = tmp_path / "cli"
    r = CliRunner().invoke(
        app, ["simulate", "--out", str(out), "--vehicles", "2", "--duration", "5", "--seed", "3"]
    )
    assert r.exit_code == 0, r.output
    assert open_recording(out).manifest.vehicles[1].id == "u2"
    bad = CliRunner().invoke(app, ["simulate", "--out", str(out), "--scenario", "moon"])
    assert bad.exit_code == 2 and "unknown scenario" in bad.output


_NUMBER = re.compile(r"-?\d+\.\d+|-?\d+")


def _same_to_last_digit(a: str, b: str) -> bool:
    """Two text lines equal except for numbers that differ by at most one unit in their last digit.

    The simulator is deterministic per machine, but libm and numpy builds differ in the last bit of
    a few transcendental results, which flips the last printed digit of a handful of values.
    """
    if _NUMBER.sub("#", a) != _NUMBER.sub("#", b):
        return False
    for x, y in zip(_NUMBER.findall(a), _NUMBER.findall(b), strict=True):
        if x == y:
            continue
        decimals = len(x.partition(".")[2])
        if len(y.partition(".")[2]) != decimals or abs(float(x) - float(y)) > 1.01 * 10.0**-decimals:
            return False
    return True


def test_bundled_default_recording_is_what_the_simulator_makes(tmp_path: Path) -> None:
    """The committed recording is the simulator's output, to the last printed digit on any machine."""
    bundled = bundled_default_path()
    assert ensure_default_recording() == bundled
    p = DEFAULT_RECORDING
    fresh = simulate(p.scenario, tmp_path / "fresh", p.vehicles, p.duration_s, p.seed)
    assert _digest(bundled).keys() == _digest(fresh).keys()
    n_last_digit = 0
    for name in sorted(_digest(bundled)):
        old = (bundled / name).read_text().splitlines()
        new = (fresh / name).read_text().splitlines()
        assert len(old) == len(new), name
        for i, (a, b) in enumerate(zip(old, new, strict=True)):
            if a != b:
                assert _same_to_last_digit(a, b), f"{name}:{i + 1}: {a!r} != {b!r}"
                n_last_digit += 1
    assert n_last_digit < 100  # a few last-digit flips, not a different simulation
    rec = open_recording(bundled)
    assert len(rec.manifest.vehicles) == 4 and len(list(rec.fleet_epochs())) == 600
    assert rec.problems.total == 0


def test_ensure_default_regenerates_into_cache_when_not_bundled(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from coplane.sim import generate

    monkeypatch.setattr(generate, "bundled_default_path", lambda: tmp_path / "absent")
    monkeypatch.setattr(generate, "DEFAULT_RECORDING", dc.replace(DEFAULT_RECORDING, duration_s=3.0))
    path = generate.ensure_default_recording(tmp_path / "cache")
    assert path == tmp_path / "cache" / "recordings" / "default"
    assert (path / "fleet.toml").is_file()
    assert generate.ensure_default_recording(tmp_path / "cache") == path  # reused, not regenerated


def test_a_relative_output_directory_gives_a_readable_recording(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """`coplane simulate --out sim` from any directory: the manifest's paths resolve inside `sim`."""
    monkeypatch.chdir(tmp_path)
    simulate("open-sky", "sim", vehicles=2, duration_s=3.0, seed=1)
    rec = open_recording(tmp_path / "sim")
    assert len(list(rec.fleet_epochs())) == 3 and rec.problems.total == 0


def test_an_earlier_simulation_is_replaced_whole_and_another_folder_refused(tmp_path: Path) -> None:
    """A 1-vehicle run over a 2-vehicle one leaves no u2 files behind (for `recording init` to
    take for the same drive); a file the simulator does not write stays; a folder holding anything
    else is refused, naming what it holds, before anything is written."""
    out = tmp_path / "sim"
    simulate("open-sky", out, vehicles=2, duration_s=3.0, seed=1)
    (out / "notes.md").write_text("mine\n")
    simulate("open-sky", out, vehicles=1, duration_s=3.0, seed=2)
    assert sorted(p.name for p in (out / "vehicles").iterdir()) == ["u1.obs"]
    assert sorted(p.name for p in (out / "truth").iterdir()) == ["u1.csv"]
    assert not (out / "uwb.csv").exists() and (out / "notes.md").read_text() == "mine\n"
    other = tmp_path / "other"
    other.mkdir()
    (other / "rover.obs").write_text("not ours\n")
    with pytest.raises(ConfigError, match=r"holds rover\.obs and no earlier output of `coplane simulate`"):
        simulate("open-sky", other, vehicles=1, duration_s=3.0, seed=1)
    assert sorted(p.name for p in other.iterdir()) == ["rover.obs"]
    # a user's recording whose name looks like a simulation's is still the user's
    (other / "vehicles").mkdir()
    (other / "fleet.toml").write_text('name = "sim drive of mine"\n')
    with pytest.raises(ConfigError, match="no earlier output"):
        simulate("open-sky", other, vehicles=1, duration_s=3.0, seed=1)
    assert sorted(p.name for p in other.iterdir()) == ["fleet.toml", "rover.obs", "vehicles"]
