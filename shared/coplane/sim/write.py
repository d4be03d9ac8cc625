"""Write a simulated fleet in the recording format: fleet.toml, nav/, base/, vehicles/, uwb.csv, truth/.

The RINEX, CSV and TOML writers are coplane.recording's; this only fills their headers. No file
contains wall-clock time, so the same seed gives byte-identical files. See docs/simulator.md
(output) and docs/recording-format.md.
"""

from __future__ import annotations

import shutil
from dataclasses import replace
from pathlib import Path

from coplane.gtime import GpsTime
from coplane.recording.csvfiles import write_uwb
from coplane.recording.manifest import write_manifest
from coplane.recording.model import BaseSpec, Manifest, ObsHeader, UwbSpec, VehicleSpec
from coplane.recording.output_dir import check_output, prepare_output
from coplane.recording.rinex_obs import DEFAULT_SIGNALS
from coplane.recording.writer import write_obs
from coplane.sim.motion import FleetTrack
from coplane.sim.result import SimResult
from coplane.sim.world import SIGNAL_TYPES

RECEIVER_NAME = "COPLANE SIM"
ANTENNA_NAME = "SIM PATCH"
BASE_ANTENNA_NAME = "SIM CHOKE RING"

SIMULATED_PARTS = ("nav", "base", "vehicles", "truth", "uwb.csv")  # what it writes besides fleet.toml
TRUTH_HEADER = "gps_week,tow_s,x_m,y_m,z_m,vx_mps,vy_mps,vz_mps,section,lane"


def _tow(tow: float) -> str:
    return f"{tow:.3f}"


def write_truth_csv(path: Path, times: list[GpsTime], track: FleetTrack, v: int) -> None:
    """truth/<id>.csv with the spec's columns plus velocity, section kind and lane (extra columns)."""
    names = track.section_names()
    lines = [TRUTH_HEADER]
    for k, t in enumerate(times):
        x, y, z = track.ecef[k, v]
        vx, vy, vz = track.vel_ecef[k, v]
        lines.append(
            f"{t.week},{_tow(t.tow)},{x:.4f},{y:.4f},{z:.4f},{vx:.4f},{vy:.4f},{vz:.4f},"
            f"{names[k, v]},{int(track.lane[k, v])}"
        )
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n", encoding="ascii", newline="\n")


def check_out_dir(out: Path) -> bool:
    """Whether `out` holds an earlier simulation to replace; a folder of anything else is refused
    before the simulation runs (`recording.output_dir`)."""
    return check_output(out, "simulate")


def write_recording(result: SimResult, out_dir: str | Path, doppler: bool = True) -> Path:
    """Write the fleet recording (fleet.toml, nav/, base/, vehicles/, uwb.csv, truth/).

    `doppler` False: the RINEX files carry no Doppler, as from a receiver or a stream that gives
    none (an RTCM MSM4 stream, many loggers' pseudorange-only RINEX); every estimator then runs
    without Doppler velocities."""
    # absolute: the manifest's paths are written relative to its root, which a relative `out_dir`
    # (e.g. `coplane simulate --out sim`) would otherwise count twice ("sim/sim/nav/...")
    out = Path(out_dir).resolve()
    prepare_output(out, "simulate", SIMULATED_PARTS)  # makes the folder too
    sc = result.scenario
    nav_rel = Path("nav") / "brdc.rnx"
    (out / "nav").mkdir(exist_ok=True)
    shutil.copyfile(result.nav_path, out / nav_rel)  # the real file, byte for byte

    obs_types: dict[str, tuple[str, ...]] = {
        sys: tuple(c for c in codes if doppler or c[0] != "D") for sys, codes in SIGNAL_TYPES.items()
    }
    signals = None if doppler else {sys: replace(DEFAULT_SIGNALS[sys], doppler=None) for sys in SIGNAL_TYPES}
    specs = []
    for v, vid in enumerate(result.vehicle_ids):
        first = result.track.ecef[0, v]
        header = ObsHeader(
            version=3.04,
            marker_name=vid,
            receiver=RECEIVER_NAME,
            antenna=ANTENNA_NAME,
            approx_position_ecef_m=(
                round(float(first[0]), 1),
                round(float(first[1]), 1),
                round(float(first[2]), 1),
            ),
            obs_types=obs_types,
            interval_s=sc.interval_s,
        )
        obs_path = out / "vehicles" / f"{vid}.obs"
        write_obs(obs_path, header, result.vehicle_obs[vid], signals=signals)
        truth_path = out / "truth" / f"{vid}.csv"
        write_truth_csv(truth_path, result.times, result.track, v)
        specs.append(VehicleSpec(vid, obs_path, float(result.track.antenna_height_m[v]), truth_path))

    base_spec = None
    if result.base_ecef is not None and sc.base is not None:
        bpos = tuple(float(x) for x in result.base_ecef)
        header = ObsHeader(
            version=3.04,
            marker_name=sc.base.name,
            receiver=RECEIVER_NAME,
            antenna=BASE_ANTENNA_NAME,
            approx_position_ecef_m=(bpos[0], bpos[1], bpos[2]),
            obs_types=obs_types,
            interval_s=sc.interval_s,
        )
        base_path = out / "base" / f"{sc.base.name}.obs"
        write_obs(base_path, header, result.base_obs, signals=signals)
        base_spec = BaseSpec(base_path, (bpos[0], bpos[1], bpos[2]))

    uwb_spec = None
    if sc.uwb is not None and len(result.vehicle_ids) > 1:
        uwb_path = out / "uwb.csv"
        write_uwb(uwb_path, result.uwb)
        uwb_spec = UwbSpec(uwb_path, sc.uwb.sigma_m, sc.uwb.max_range_m)

    manifest = Manifest(
        root=out,
        name=f"sim {sc.name} seed {result.seed}: {len(result.vehicle_ids)} vehicles, {len(result.times)} epochs",
        interval_s=sc.interval_s,
        nav_files=(out / nav_rel,),
        vehicles=tuple(specs),
        base=base_spec,
        uwb=uwb_spec,
    )
    write_manifest(manifest)
    return out
