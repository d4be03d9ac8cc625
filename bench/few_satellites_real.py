"""Receiver clocks and few satellites on real receivers (docs/fgo.md, "Few satellites on a real receiver").

    .venv/bin/python bench/few_satellites_real.py --out docs/fgo.md          # ~2 min, 1 core
    .venv/bin/python bench/few_satellites_real.py --sim --out docs/fgo.md    # + the simulator, ~15 min

Two checks the simulator cannot make, because its receiver clocks are far steadier than a real
TCXO and it shares its multipath model with the library:

1. **Clock drift.** Per set of ../shared/data/real with a static receiver or a drive, the Doppler
   clock drift of every epoch with a full-sky velocity solution, and how much it changes over a
   lag: the standard deviation, 99th percentile and maximum of drift(t + lag) - drift(t).
2. **Few satellites.** The static F9P in HK TST, GPS + BeiDou only (as a u-blox M8T tracks), with
   three stretches of 20, 45 and 90 s in which only 3 or 4 satellites remain, drawn per seed
   (`coplane.evaluate.few_satellites`). Per seed: the largest horizontal and vertical error inside
   the stretches, for `non-cp` with its defaults, with the paper's GNSS front end (a Doppler
   velocity needs 5 satellites; the default solves 3-4 with a level-road and a carried-drift row,
   `coplane.gnss.doppler`), without the standstill test (`coplane.gnss.standstill`: few Doppler
   rows that show the receiver standing give a zero velocity, and the graph dead-reckons that
   epoch), with each factor-graph opt-in (bench/tune_fgo.py's variants
   `drop-undetermined`, `carry-drift`, `carry-drift-wander`: 0.2 m/s per second, twice part 1's
   wander; `no-isb`: each system's clock free, as before one receiver clock with an offset per other
   system became a default; `cv-0.0625`: a constant velocity and clock drift over the last three states), and
   for the EKF baseline
   `non-cp-ekf` with each front end.
   2b. **A moving car.** The Kowloon Tong drive has no truth: the full-sky DGNSS `non-cp`
   solution is the reference, and the drive is thinned to 3 or 4 satellites in three stretches.
   2c. **Recovery.** Both sets again, with the largest errors *outside* the stretches, where the
   full sky is back: the defaults, without the FDE's restart of a diverged track
   (`fde-no-restart`), and with the rule before both (`fde-first-test-only`: the prediction was
   rejected only on its first test's failures).
3. **The simulator** (`--sim`): `non-cp` and `pc`, with DGNSS, on the dense-urban training seeds
   (coplane.evaluate.benchmark.TRAINING), whose canyons leave vehicles with few satellites, and
   `pc` on urban-loop 101-103: the defaults against the same alternatives.

The few-satellite front end became the default on parts 2, 2b and 3 together: it gained on the
car with 4 satellites, on the static antenna and on the training seeds (docs/fgo.md). No factor-
graph opt-in did. No held-out seed was looked at. The FDE's divergence rules (part 2c) became
defaults on parts 2c and 3 and the training seeds of bench/tune_fgo.py, checked on the validation
seeds. The standstill test became the default on parts 2 and 2b (its detectable speed, 2 m/s,
is the largest that took no epoch of the moving car's 3-satellite stretches for a standstill) and changed
nothing in part 3, whose vehicles never stand. One receiver clock with an offset per other system became
the default on parts 2, 2b and 3 and bench/tune_fgo.py's training seeds, checked on the
validation seeds (docs/tuning-validation-isb.md).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from docblock import write_block
from real_data_regression import REAL
from tune_fgo import apply_variant

from coplane.evaluate.benchmark import TRAINING, make_recordings, pooled_by_environment
from coplane.evaluate.few_satellites import CAR_STRETCHES, DEFAULT_STRETCHES, FewSatelliteRecording, Stretch
from coplane.evaluate.real_data import truth_of
from coplane.evaluate.runner import run_method
from coplane.evaluate.spp_run import run_spp
from coplane.geo import ecef_to_geodetic, enu_rotation
from coplane.gnss.doppler import DopplerOptions
from coplane.gnss.epoch_solver import EpochSolverOptions, ReceiverMemory, solve_epoch
from coplane.gnss.standstill import StandstillOptions
from coplane.methods import MethodSpec, get_method
from coplane.recording.reader import Recording, open_recording

COMMAND = ".venv/bin/python bench/few_satellites_real.py --out docs/fgo.md"
DRIFT_SETS = (
    "urbannav_hk_tst_20200603_static_f9p",
    "matrtklib_nagoya_static_20240624",
    "hk_klt_20210610_f9p_rover_hksc_base",
)
THINNED_SET = "urbannav_hk_tst_20200603_static_f9p"
MOVING_SET = "hk_klt_20210610_f9p_rover_hksc_base"
LAGS_S = (1, 5, 10, 30, 60, 90)


# The defaults and the alternatives: bench/tune_fgo.py variants of the factor graph, and the GNSS
# front end of the paper (a Doppler velocity needs 5 satellites) instead of the few-satellite mode.
FGO_VARIANTS = {
    "default": "defaults",
    "drop-undetermined": "undetermined epochs dead-reckoned",
    "carry-drift": "last drift carried",
    "carry-drift-wander": "last drift carried, sigma from its wander",
    "no-isb": "clocks free",
    "cv-0.0625": "constant velocity and drift",
}
PAPER_FRONT_END = EpochSolverOptions(doppler=DopplerOptions(few_satellites=False))
NO_STANDSTILL = EpochSolverOptions(doppler=DopplerOptions(standstill=StandstillOptions(enabled=False)))


@dataclass(frozen=True)
class Variant:
    """A method and the vehicles' GNSS front end it runs with (None: the default one)."""

    method: Callable[[], MethodSpec]
    front_end: EpochSolverOptions | None = None


VARIANTS: dict[str, Variant] = {
    "non-cp (defaults)": Variant(lambda: get_method("non-cp")),
    "non-cp, paper front end": Variant(lambda: get_method("non-cp"), PAPER_FRONT_END),
    "non-cp, no standstill test": Variant(lambda: get_method("non-cp"), NO_STANDSTILL),
    **{
        f"non-cp, {label}": Variant(lambda n=name: apply_variant(get_method("non-cp"), n))
        for name, label in FGO_VARIANTS.items()
        if name != "default"
    },
    "non-cp-ekf": Variant(lambda: get_method("non-cp-ekf")),
    "non-cp-ekf, paper front end": Variant(lambda: get_method("non-cp-ekf"), PAPER_FRONT_END),
    "non-cp-ekf, no standstill test": Variant(lambda: get_method("non-cp-ekf"), NO_STANDSTILL),
}


def drift_series(rec: Recording) -> tuple[np.ndarray, np.ndarray]:
    """Times (s) and Doppler clock drifts (m/s) of the first receiver's epochs with a full-sky
    velocity (5 or more Doppler measurements: no drift memory in it)."""
    vid = rec.manifest.vehicles[0].id
    times, drifts = [], []
    at = None
    for e in rec.vehicle_epochs(vid):
        r = solve_epoch(e, rec.nav, initial_position=at)
        if r.spp.ok:
            at = r.spp.position
        if r.velocity is not None and r.velocity.ok and not r.velocity.few_satellites:
            times.append(e.time.seconds)
            drifts.append(r.velocity.drift_mps)
    return np.asarray(times), np.asarray(drifts)


def drift_table() -> str:
    rows = [
        "| set | epochs with drift | drift range (m/s) | "
        + " | ".join(f"{lag} s: std / p99 / max" for lag in LAGS_S)
        + " |",
        "|---|---|---|" + "---|" * len(LAGS_S),
    ]
    for name in DRIFT_SETS:
        t, d = drift_series(open_recording(REAL / name))
        cells = []
        for lag in LAGS_S:
            j = np.searchsorted(t, t + lag - 0.01)
            ok = j < len(t)
            ok[ok] &= np.abs(t[j[ok]] - t[ok] - lag) < 0.1
            change = np.abs(d[j[ok]] - d[ok])
            cells.append(
                f"{np.std(d[j[ok]] - d[ok]):.2f} / {np.percentile(change, 99):.2f} / {change.max():.2f}"
                if len(change)
                else "-"
            )
        rows.append(f"| `{name}` | {len(t)} | {d.min():.1f} .. {d.max():.1f} | " + " | ".join(cells) + " |")
    return "\n".join(rows)


def velocity_strength_table() -> str:
    """Part 1b: how strong the Doppler velocities are, full-sky and few-satellite, in their weakest
    direction (the 1-sigma that `DopplerOptions.few_max_sigma_mps` bounds for the few-satellite
    ones): the unthinned drive and static set, and both thinned with seed 1. Standstills
    (`coplane.gnss.standstill`) are counted apart: theirs is the speed the test could miss. The
    last column is the receiver's Doppler variance factor that the standstill test learns from
    the full-sky solves (`standstill.DopplerNoise`, as `epoch_solver.ReceiverMemory` keeps it)."""
    rows = [
        "| set | velocities: full sky / few satellites / standstills | full sky: p10 / median / p90 / p99 (m/s) | few satellites: median / max (m/s) | learned Doppler variance factor: median / max over the epochs |",
        "|---|---|---|---|---|",
    ]
    opt = DopplerOptions().standstill
    for name, dgnss, stretches in (
        (MOVING_SET, True, CAR_STRETCHES),
        (THINNED_SET, False, DEFAULT_STRETCHES),
    ):
        raw = open_recording(REAL / name)
        for label, rec in (
            (f"`{name}`", raw),
            (f"`{name}`, 4 satellites, seed 1", FewSatelliteRecording(raw, stretches, keep=4)),
        ):
            full, few, still, factors = [], [], 0, []
            for run in run_spp(rec, dgnss=dgnss).values():
                memory = ReceiverMemory()  # replays the noise the agent's front end learns
                for _, res in sorted(run.results.items()):
                    memory.update(res)
                    factors.append(memory.doppler_noise.factor(opt))
                    v = res.velocity
                    if v is not None and v.ok and v.standstill:
                        still += 1
                    elif v is not None and v.ok:
                        worst = float(np.sqrt(np.linalg.eigvalsh(v.covariance)[-1]))
                        (few if v.few_satellites else full).append(worst)
            p = np.percentile(full, [10, 50, 90, 99])
            few_cells = f"{np.median(few):.2f} / {max(few):.2f}" if few else "-"
            rows.append(
                f"| {label} | {len(full)} / {len(few)} / {still} | {p[0]:.2f} / {p[1]:.2f} / {p[2]:.2f} / {p[3]:.2f} | {few_cells} | {np.median(factors):.2f} / {max(factors):.2f} |"
            )
    return "\n".join(rows)


SEEDS = (1, 2, 3, 4, 5, 6)
KEEPS = (3, 4)


def stretch_worst(
    rec: FewSatelliteRecording, positions: dict, truth: dict, inside: bool = True
) -> tuple[float, float, float]:
    """Largest horizontal and vertical error inside the stretches (`inside=False`: outside them,
    where the full sky is back; NaN: none solved there), and the availability."""
    t0 = min(truth).seconds
    h, v = [float("nan")], [float("nan")]
    for t, x in truth.items():
        p = positions.get(t)
        if p is None or rec.in_stretch(t.seconds - t0) != inside:
            continue
        d = enu_rotation(*ecef_to_geodetic(np.asarray(x))[:2]) @ (np.asarray(p) - np.asarray(x))
        h.append(float(np.hypot(d[0], d[1])))
        v.append(abs(float(d[2])))
    return float(np.nanmax(h)), float(np.nanmax(v)), sum(1 for t in truth if t in positions) / len(truth)


def stretch_list(stretches: Iterable[Stretch]) -> str:
    """'100-120 s, 300-345 s, ...': where the thinned stretches lie, for a table's caption."""
    return ", ".join(f"{s.start_s:.0f}-{s.start_s + s.length_s:.0f} s" for s in stretches)


def worst_table(
    raw: Recording,
    stretches: Sequence[Stretch],
    reference: dict,
    dgnss: bool,
    variants: dict[str, Variant] | None = None,
    inside: bool = True,
) -> tuple[list[str], float]:
    """`raw` thinned to each of KEEPS satellites for each of SEEDS: a Markdown table (header
    included) with every variant's (default: VARIANTS) largest horizontal / vertical error inside
    the stretches (`inside=False`: outside them) against `reference`; and the least availability
    of any run."""
    variants = VARIANTS if variants is None else variants
    vid = raw.manifest.vehicles[0].id
    rows = ["| satellites left | seed | " + " | ".join(variants) + " |", "|---|---|" + "---|" * len(variants)]
    least_avail = 1.0
    for keep in KEEPS:
        for seed in SEEDS:
            rec = FewSatelliteRecording(raw, stretches, keep=keep, seed=seed)
            cells = []
            for var in variants.values():
                run = run_method(
                    rec, var.method(), dgnss=dgnss, vehicles=[vid], jobs=1, front_end=var.front_end
                )
                h, v, avail = stretch_worst(rec, run.positions.get(vid, {}), reference, inside)
                least_avail = min(least_avail, avail)
                cells.append(f"{h:.1f} / {v:.1f}")
            rows.append(f"| {keep} | {seed} | " + " | ".join(cells) + " |")
            print(rows[-1], flush=True)
    return rows, least_avail


def few_satellites_table() -> str:
    """Part 2: the static F9P against its surveyed truth, standalone."""
    raw = open_recording(REAL / THINNED_SET)
    truth = truth_of(raw, raw.manifest.vehicles[0].id)
    rows, least_avail = worst_table(raw, DEFAULT_STRETCHES, truth, dgnss=False)
    return (
        f"`{THINNED_SET}`, GPS + BeiDou, standalone; stretches {stretch_list(DEFAULT_STRETCHES)} after the "
        "first epoch, in which each epoch keeps the first 3 or 4 tracked satellites of a ranking drawn from "
        "the seed. Largest horizontal / vertical error inside the stretches (m). Every method solved at "
        f"least {least_avail:.1%} of the {len(truth)} truth epochs.\n\n" + "\n".join(rows)
    )


def moving_reference(raw: Recording) -> dict:
    """The moving F9P's pseudo-truth: its full-sky DGNSS `non-cp` solution (metres, not decimetres)."""
    vid = raw.manifest.vehicles[0].id
    return run_method(raw, get_method("non-cp"), dgnss=True, vehicles=[vid], jobs=1).positions[vid]


def moving_table() -> str:
    """Part 2b: the moving F9P (no truth), thinned to 3 or 4 satellites; the deviation from the
    full-sky DGNSS `non-cp` solution inside the stretches."""
    raw = open_recording(REAL / MOVING_SET)
    rows, _ = worst_table(raw, CAR_STRETCHES, moving_reference(raw), dgnss=True)
    return (
        f"`{MOVING_SET}`, a car, DGNSS; stretches {stretch_list(CAR_STRETCHES)} with 3 or 4 satellites. "
        "Largest horizontal / vertical distance (m) inside the stretches from the full-sky `non-cp` "
        "solution.\n\n" + "\n".join(rows)
    )


# The FDE's divergence rules (docs/fgo.md, "A diverged track comes back"): the defaults, without
# the restart, and the rule before both (the prediction rejected only on the first test's failures).
# The far-snapshot rule (docs/fgo.md, "A right prediction against a far snapshot") is a default
# since 2026-11-30; the last row is the defaults without it.
RECOVERY_RULES = {
    "fde-no-restart": "no restart",
    "fde-first-test-only": "first test only",
    "no-far-snapshot-rule": "no far-snapshot rule",
}
RECOVERY_VARIANTS: dict[str, Variant] = {
    "non-cp (defaults)": Variant(lambda: get_method("non-cp")),
    **{
        f"non-cp, {label}": Variant(lambda n=name: apply_variant(get_method("non-cp"), n))
        for name, label in RECOVERY_RULES.items()
    },
}


def recovery_table() -> str:
    """Part 2c: after the stretches, when the full sky is back: the largest errors outside them,
    for the static F9P (truth) and the car (pseudo-truth)."""
    parts = []
    for name, stretches, dgnss in (
        (THINNED_SET, DEFAULT_STRETCHES, False),
        (MOVING_SET, CAR_STRETCHES, True),
    ):
        raw = open_recording(REAL / name)
        reference = truth_of(raw, raw.manifest.vehicles[0].id) if not dgnss else moving_reference(raw)
        rows, _ = worst_table(raw, stretches, reference, dgnss, RECOVERY_VARIANTS, inside=False)
        against = "its full-sky `non-cp` solution" if dgnss else "the surveyed truth"
        parts.append(
            f"`{name}`, {'DGNSS' if dgnss else 'standalone'}, stretches {stretch_list(stretches)}: largest "
            f"horizontal / vertical distance (m) from {against} *outside* the stretches.\n\n"
            + "\n".join(rows)
        )
    return "\n\n".join(parts)


SIM_RUNS = {"dense-urban": ("non-cp", "pc"), "urban-loop": ("pc",)}
SIM_SEEDS = {"dense-urban": TRAINING["dense-urban"], "urban-loop": TRAINING["urban-loop"][:3]}


def simulator_table() -> str:
    """Part 3: pooled H / V RMSE of the defaults and the alternatives on training seeds."""
    columns: dict[str, tuple[str, EpochSolverOptions | None]] = {
        **{label: (name, None) for name, label in FGO_VARIANTS.items()},
        **{label: (name, None) for name, label in RECOVERY_RULES.items()},
        "paper front end": ("default", PAPER_FRONT_END),
        "no standstill test": ("default", NO_STANDSTILL),
    }
    rows = [
        "| scenario, seeds | method | " + " | ".join(f"{label} H / V (m)" for label in columns) + " |",
        "|---|---|" + "---|" * len(columns),
    ]
    with tempfile.TemporaryDirectory() as tmp:
        for scen, methods in SIM_RUNS.items():
            recs = make_recordings(scen, SIM_SEEDS[scen], Path(tmp), 4, 200.0)
            for method in methods:
                cells = []
                for name, front_end in columns.values():
                    spec = (
                        get_method(method) if name == "default" else apply_variant(get_method(method), name)
                    )
                    stats = pooled_by_environment(recs, spec, front_end=front_end)[0]["all"]
                    cells.append(f"{stats.h_rmse_m:.2f} / {stats.v_rmse_m:.2f}")
                seeds = ", ".join(map(str, SIM_SEEDS[scen]))
                rows.append(f"| {scen} {seeds} | {method} | " + " | ".join(cells) + " |")
                print(rows[-1], flush=True)
    return "\n".join(rows)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=None, help="docs page with the generated blocks")
    ap.add_argument("--sim", action="store_true", help="also part 3, the simulator's training seeds")
    args = ap.parse_args()
    drift = drift_table()
    print(drift, flush=True)
    strength = velocity_strength_table()
    print(strength, flush=True)
    if args.out is not None:
        write_block(args.out, "velocity_strength_real", COMMAND, strength)
    few = few_satellites_table()
    print(few)
    if args.out is not None:
        write_block(args.out, "clock_drift_real", COMMAND, drift)
        write_block(args.out, "few_satellites_real", COMMAND, few)
    moving = moving_table()
    print(moving)
    if args.out is not None:
        write_block(args.out, "few_satellites_moving", COMMAND, moving)
    recovery = recovery_table()
    print(recovery)
    if args.out is not None:
        write_block(args.out, "few_satellites_recovery", COMMAND, recovery)
    if args.sim:
        sim = simulator_table()
        if args.out is not None:
            write_block(args.out, "few_satellites_sim", COMMAND.replace(" --out", " --sim --out"), sim)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
