"""Generate a fleet recording: build the world, step every epoch, collect observations and UWB.

The pieces, in the order they run: coplane.sim.world (navigation data, road, canyon, fleet
motion), coplane.sim.epoch (per epoch: coplane.sim.sky geometry, coplane.sim.visibility canyon,
coplane.sim.tracking C/N0, coplane.sim.injection errors -> pseudorange, Doppler, C/N0),
coplane.sim.uwb (inter-vehicle ranges), then coplane.sim.write. Every random draw comes from a
named, seed-derived numpy stream, so the same seed gives byte-identical files. The measurement
model and its sources are in docs/simulator.md.
"""

from __future__ import annotations

import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from tqdm import tqdm

from coplane.recording.model import ObsEpoch, UwbRange
from coplane.sim.diagnostics import Diagnostics
from coplane.sim.epoch import EpochSimulator
from coplane.sim.errors import component_rng
from coplane.sim.result import SimResult
from coplane.sim.road import RoadRaise
from coplane.sim.scenarios import DEFAULT_SCENARIO, Scenario, get_scenario
from coplane.sim.uwb import UwbSimulator
from coplane.sim.world import build_world
from coplane.sim.write import check_out_dir, write_recording


def run_simulation(
    scenario: Scenario | str = DEFAULT_SCENARIO,
    vehicles: int = 4,
    duration_s: float = 600.0,
    seed: int = 0,
    progress: bool = False,
    diagnostics: bool = False,
    on_epoch: Callable[[int, int], None] | None = None,
    start_offset_s: float = 0.0,
    road_raise: tuple[RoadRaise, ...] = (),
) -> SimResult:
    """Simulate in memory. `vehicles` >= 1; `duration_s` / interval epochs; the drive starts
    `start_offset_s` after the scenario's start time (same roads, another sky) and `road_raise` re-surfaces road sections."""
    sc = get_scenario(scenario) if isinstance(scenario, str) else scenario
    world = build_world(sc, vehicles, duration_s, seed, start_offset_s, road_raise)
    epochs = EpochSimulator(world, seed, broadcast_iono=diagnostics)
    n_ep, m, ids = len(world.times), world.vehicles, world.track.ids
    uwb_sim = None
    if sc.uwb is not None and m > 1:
        uwb_sim = UwbSimulator(m, sc.uwb, world.canyon.footprint_grid(), component_rng(seed, "uwb"))
    diag = Diagnostics.empty(n_ep, world.n_rx, world.sats, epochs.errors.clocks) if diagnostics else None

    vehicle_obs: dict[str, list[ObsEpoch]] = {vid: [] for vid in ids}
    base_obs: list[ObsEpoch] = []
    uwb_rows: list[UwbRange] = []
    uwb_kinds: list[int] = []
    for k in tqdm(range(n_ep), desc="simulate", unit="epoch", disable=not progress):
        ep = epochs.step(k)
        for r, obs in enumerate(ep.obs):
            (vehicle_obs[ids[r]] if r < m else base_obs).append(obs)
        if uwb_sim is not None:
            t = world.times[k]
            u = uwb_sim.step(world.track.ecef[k], world.track.enu[k][:, :2])
            for a_i, b_i, rg, kd in zip(u.i, u.j, u.range_m, u.nlos, strict=True):
                uwb_rows.append(UwbRange(t, ids[int(a_i)], ids[int(b_i)], round(float(rg), 4)))
                uwb_kinds.append(int(kd))
        if diag is not None:
            diag.record(k, ep)
        if on_epoch is not None:
            on_epoch(k + 1, n_ep)

    return SimResult(
        scenario=sc,
        seed=seed,
        times=world.times,
        vehicle_ids=ids,
        track=world.track,
        road=world.road,
        sections=world.sections,
        canyon=world.canyon,
        nav=world.nav,
        nav_path=world.nav_path,
        vehicle_obs=vehicle_obs,
        base_obs=base_obs,
        base_ecef=world.base_ecef,
        uwb=uwb_rows,
        diagnostics=diag,
        uwb_kinds=uwb_kinds,
    )


def simulate(
    scenario: Scenario | str = DEFAULT_SCENARIO,
    out_dir: str | Path = "sim-recording",
    vehicles: int = 4,
    duration_s: float = 600.0,
    seed: int = 0,
    progress: bool = False,
    start_offset_s: float = 0.0,
    doppler: bool = True,
) -> Path:
    """Simulate a fleet and write the recording; returns its directory. `doppler` False: the
    receivers log no Doppler (`write_recording`). A folder it may not write into is refused before
    the simulation runs (`check_out_dir`)."""
    check_out_dir(Path(out_dir).resolve())
    result = run_simulation(scenario, vehicles, duration_s, seed, progress, start_offset_s=start_offset_s)
    return write_recording(result, out_dir, doppler)


# --- the bundled default recording --------------------------------------------------------------


@dataclass(frozen=True)
class DefaultRecording:
    """How the bundled default recording is made (README and `coplane fleet` replay it)."""

    scenario: str = DEFAULT_SCENARIO
    vehicles: int = 4
    duration_s: float = 600.0
    seed: int = 0


DEFAULT_RECORDING = DefaultRecording()


def bundled_default_path() -> Path:
    """Where the committed default recording lives inside the package (coplane/data/recordings)."""
    from coplane.sim.scenarios import bundled_nav_path

    return bundled_nav_path().parent.parent / "recordings" / "default"


def ensure_default_recording(cache_dir: str | Path | None = None) -> Path:
    """The default recording (urban-loop, 4 vehicles, 600 s, seed 0), ready to replay.

    The package ships it (coplane/data/recordings/default, 4.3 MB; tests check it is exactly what
    the simulator produces). If that copy is missing (e.g. a slimmed install), it is generated
    once, deterministically, into `cache_dir` (default $COPLANE_CACHE_DIR or ~/.cache/coplane)
    and reused from there.
    """
    import os
    import tempfile

    bundled = bundled_default_path()
    if (bundled / "fleet.toml").is_file():
        return bundled
    root = Path(cache_dir or os.environ.get("COPLANE_CACHE_DIR") or Path.home() / ".cache" / "coplane")
    target = root / "recordings" / "default"
    if (target / "fleet.toml").is_file():
        return target
    root.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix="default-", dir=root))
    p = DEFAULT_RECORDING
    simulate(p.scenario, tmp, p.vehicles, p.duration_s, p.seed)
    target.parent.mkdir(parents=True, exist_ok=True)
    try:
        tmp.rename(target)  # atomic: a concurrent first use never sees a half-written recording
    except OSError:
        shutil.rmtree(tmp, ignore_errors=True)
        if not (target / "fleet.toml").is_file():
            raise
    return target
