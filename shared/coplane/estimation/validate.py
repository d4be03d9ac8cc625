"""One input check for every estimator: an untrusted `EpochInput` in, validated arrays out.

Estimator inputs come from the bus (or a recording) and are untrusted even after the wire models
checked them: an estimator must never raise on data, never let a NaN or an absurd value reach its
solver, and must count what it dropped. The factor graph and every baseline used to do this each
in its own way, with drifted limits; `validate_epoch` is now the one place. It never raises: bad
measurements are dropped and counted in `ValidEpoch.rejected` by kind, and a vehicle that cannot be
used at all is listed in `ValidEpoch.skipped` with the reason.

Limits: `coplane.estimation.limits`. Model of the arrays: docs/fgo.md (pseudorange factor).
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Collection, Sequence
from dataclasses import dataclass, field
from typing import TypeGuard, cast

import numpy as np

from coplane.estimation.contract import (
    EpochInput,
    FleetSolution,
    PlaneObs,
    PseudorangeColumns,
    PseudorangeObs,
    VehicleEpochInput,
)
from coplane.estimation.limits import (
    KNOWN_SYSTEMS,
    MAX_ANTENNA_HEIGHT_M,
    MAX_DRIFT_MPS,
    MAX_NORMAL_ERROR,
    MAX_PLANE_SIGMA_M,
    MAX_RANGE_M,
    MAX_RANGE_SIGMA_M,
    MAX_SAT_CLOCK_S,
    MAX_SIGMA_M,
    MAX_SPEED_MPS,
    PSEUDORANGE_M,
    RECEIVER_RADIUS_M,
    SAT_RADIUS_M,
)
from coplane.gtime import GpsTime
from coplane.numeric import norm3
from coplane.typing import Mat, Vec

MAX_EPOCH_MISMATCH_S = 0.5  # a vehicle's epoch time may differ this much from the fleet epoch's


def finite(x: object) -> float | None:
    """`x` as a finite float, or None (for values of unknown type from untrusted input)."""
    try:
        f = float(x)  # type: ignore[arg-type]
    except (TypeError, ValueError, OverflowError):  # OverflowError: an int beyond a float's range
        return None
    return f if math.isfinite(f) else None


def finite_vec3(v: object) -> Vec | None:
    """`v` as a finite 3-vector (a fresh array), or None."""
    try:
        a = np.asarray(v, dtype=float).reshape(-1)
    except (TypeError, ValueError, OverflowError):
        return None
    return a.copy() if a.shape == (3,) and bool(np.all(np.isfinite(a))) else None


@dataclass(frozen=True)
class ValidPseudoranges:
    """One vehicle epoch's plausible, de-duplicated pseudoranges as arrays (one row per satellite).

    Model: rho = |p - sat_pos| + c (clock[system] - sat_clock) + noise(sigma), with sat_pos in the
    ECEF frame at reception; elevation and C/N0 are NaN where the node did not report them.
    """

    sats: list[str]
    systems: list[str]  # the system letter of each row (sats[i][0])
    sat_pos: Mat  # (n, 3) metres
    rho: Vec  # (n,) metres
    sat_clock: Vec  # (n,) seconds
    sigma: Vec  # (n,) metres
    elevation: Vec  # (n,) radians
    cn0: Vec  # (n,) dB-Hz
    # (n,) metres, the error common to the window's epochs (`PseudorangeObs.common_sigma_m`);
    # NaN where unknown, None when unknown for every row
    common_sigma: Vec | None = None

    def __len__(self) -> int:
        return len(self.sats)

    def subset(self, keep: Sequence[int] | Vec) -> ValidPseudoranges:
        """The rows `keep` (indices or a boolean mask), in order."""
        idx = np.flatnonzero(keep) if np.asarray(keep).dtype == bool else np.asarray(keep, dtype=int)
        rows = idx.tolist()
        return ValidPseudoranges(
            [self.sats[i] for i in rows],
            [self.systems[i] for i in rows],
            self.sat_pos[idx].reshape(-1, 3),
            self.rho[idx],
            self.sat_clock[idx],
            self.sigma[idx],
            self.elevation[idx],
            self.cn0[idx],
            None if self.common_sigma is None else self.common_sigma[idx],
        )


@dataclass(frozen=True)
class ValidVehicle:
    """One vehicle's validated epoch: what an estimator may use, and nothing that could hurt it."""

    vehicle_id: str
    pseudoranges: ValidPseudoranges
    velocity: Vec | None = None  # Doppler velocity, ECEF m/s
    velocity_sigma: float = math.nan  # its 1-sigma per axis (finite when velocity is given)
    plane: PlaneObs | None = None
    spp: Vec | None = None  # the node's SPP fix (initial guess)
    drift: float | None = None  # Doppler receiver clock drift, m/s
    antenna_height_m: float | None = None  # above the road, 0-10 m
    standstill: bool = False  # the velocity is a detected standstill's zero
    doppler_observed: bool | None = True  # VehicleEpochInput.doppler_observed


@dataclass(frozen=True)
class ValidRange:
    """An inter-vehicle range with a < b; sigma_m is NaN when the node gave no usable sigma."""

    a: str
    b: str
    range_m: float
    sigma_m: float

    def sigma_or(self, default: float) -> float:
        """The range's own sigma, or the estimator's default when it had none."""
        return self.sigma_m if math.isfinite(self.sigma_m) else default


@dataclass
class ValidEpoch:
    """A fleet epoch after validation: per-vehicle arrays, ranges, and what was dropped."""

    time: GpsTime
    vehicles: dict[str, ValidVehicle]
    ranges: list[ValidRange]  # one per pair, sorted by pair; vehicles may be absent from `vehicles`
    skipped: dict[str, str] = field(default_factory=dict)  # vehicle -> why it cannot be used
    rejected: Counter[str] = field(default_factory=Counter)  # kind -> measurements dropped

    def ranges_between(self, present: Collection[str]) -> list[ValidRange]:
        """The ranges whose two vehicles are both in `present`."""
        return [r for r in self.ranges if r.a in present and r.b in present]


def out_of_order_reason(epoch: EpochInput, last: GpsTime | None) -> str | None:
    """Why `epoch` cannot follow the previous epoch `last` (time not after it, or malformed)."""
    try:
        ok = last is None or epoch.time - last > 0.0
    except Exception:  # untrusted input: a malformed time is out of order too
        ok = False
    return None if ok else f"epoch time {getattr(epoch, 'time', '?')} is not after the previous epoch {last}"


def validate_epoch(epoch: EpochInput, *, planes: bool = True, ranges: bool = True) -> ValidEpoch:
    """Validate every vehicle and range of one fleet epoch; never raises.

    `planes=False` / `ranges=False`: the estimator does not use them, so they are neither checked
    nor counted as rejected.
    """
    out = ValidEpoch(epoch.time, {}, [])
    for vid in sorted(epoch.vehicles):
        got = validate_vehicle(vid, epoch.vehicles[vid], epoch.time, out.rejected, planes=planes)
        if isinstance(got, str):
            out.skipped[vid] = got
        else:
            out.vehicles[vid] = got
    if ranges:
        out.ranges = _valid_ranges(epoch, out.rejected)
    return out


def validate_vehicle(
    vid: str, vin: object, t: GpsTime, rejected: Counter[str], *, planes: bool = True
) -> ValidVehicle | str:
    """One vehicle's validated measurements, or the reason it cannot be used at all."""
    if not isinstance(vin, VehicleEpochInput) or vin.vehicle_id != vid:
        rejected["vehicle"] += 1
        return "vehicle input does not match its id"
    try:
        dt = abs(vin.time - t)
    except (TypeError, AttributeError):
        dt = math.inf
    if not dt <= MAX_EPOCH_MISMATCH_S:
        rejected["vehicle"] += 1
        return f"vehicle epoch time {vin.time} is not the epoch's time {t}"
    prs = _valid_pseudoranges(vin.pseudoranges or (), rejected)
    velocity, vsig, standstill = None, math.nan, False
    if vin.velocity is not None:
        velocity = finite_vec3(getattr(vin.velocity, "velocity_mps", None))
        s = finite(getattr(vin.velocity, "sigma_mps", None))
        if velocity is None or norm3(velocity) > MAX_SPEED_MPS or s is None or not s > 0:
            rejected["velocity"] += 1
            velocity = None
        else:
            vsig = s
            # a claim of standing with a nonzero velocity is a contradiction, not a standstill
            standstill = getattr(vin.velocity, "standstill", False) is True
            if standstill and np.any(velocity):
                rejected["standstill"] += 1
                standstill = False
    drift = None
    if vin.clock_drift_mps is not None:
        drift = finite(vin.clock_drift_mps)
        if drift is None or abs(drift) > MAX_DRIFT_MPS:
            rejected["clock_drift"] += 1
            drift = None
    spp = None
    if vin.spp_position is not None:
        spp = finite_vec3(vin.spp_position)
        if spp is None or not RECEIVER_RADIUS_M[0] <= norm3(spp) <= RECEIVER_RADIUS_M[1]:
            rejected["spp"] += 1
            spp = None
    plane = _valid_plane(vin.plane, rejected) if planes else None
    antenna = None
    if vin.antenna_height_m is not None:
        antenna = finite(vin.antenna_height_m)
        if antenna is None or not 0.0 <= antenna <= MAX_ANTENNA_HEIGHT_M:
            rejected["antenna_height"] += 1
            antenna = None
    doppler = vin.doppler_observed
    if doppler is not None and not isinstance(doppler, bool):
        rejected["doppler_observed"] += 1
        doppler = True  # not a yes or no: taken as a receiver with Doppler (the estimator's usual case)
    return ValidVehicle(vid, prs, velocity, vsig, plane, spp, drift, antenna, standstill, doppler)


def _valid_pseudoranges(
    prs: Sequence[PseudorangeObs] | PseudorangeColumns, rejected: Counter[str]
) -> ValidPseudoranges:
    """Plausible, de-duplicated pseudoranges as arrays (vectorised: this runs per vehicle epoch)."""
    ids_in, sats, num = _pseudorange_rows(prs)
    n = len(ids_in)
    with np.errstate(invalid="ignore", over="ignore"):
        radius = np.sqrt(np.einsum("ij,ij->i", sats, sats))
        ok = (  # the wire models' bounds (inclusive), so what passes the wire passes here
            (radius >= SAT_RADIUS_M[0])
            & (radius <= SAT_RADIUS_M[1])
            & (num[:, 0] >= PSEUDORANGE_M[0])
            & (num[:, 0] <= PSEUDORANGE_M[1])
            & (np.abs(num[:, 1]) <= MAX_SAT_CLOCK_S)
            & (num[:, 2] > 0.0)
            & (num[:, 2] <= MAX_SIGMA_M)
        )
    ids = cast(list[str], list(ids_in))  # the usual epoch keeps every row, without the row loop
    if not (bool(ok.all()) and all(map(_plausible_id, ids)) and len(set(ids)) == n):
        keep: list[int] = []
        seen: set[str] = set()
        for i, good in enumerate(ok.tolist()):
            sat = ids_in[i]
            if good and _plausible_id(sat) and sat not in seen:
                seen.add(sat)
                keep.append(i)
        if len(keep) < n:
            rejected["pseudorange"] += n - len(keep)
            sats, num = sats[keep], num[keep]
        ids = [cast(str, ids_in[i]) for i in keep]
    extra = num[:, 3:]  # elevation, C/N0, common sigma are optional: anything not finite is unknown
    extra[~np.isfinite(extra)] = np.nan
    with np.errstate(invalid="ignore"):
        common = num[:, 5]
        common[~((common >= 0.0) & (common <= MAX_SIGMA_M))] = np.nan  # not a measurement: unknown
    return ValidPseudoranges(
        ids,
        [s[0] for s in ids],
        sats,
        num[:, 0],
        num[:, 1],
        num[:, 2],
        num[:, 3],
        num[:, 4],
        None if bool(np.isnan(common).all()) else common,
    )


def _plausible_id(sat: object) -> TypeGuard[str]:
    """A satellite id of a known system ('G05'): what the row loop of `_valid_pseudoranges` keeps."""
    return isinstance(sat, str) and len(sat) >= 2 and sat[0] in KNOWN_SYSTEMS


def _pseudorange_rows(prs: object) -> tuple[list[object], Mat, Mat]:
    """Each row's satellite id, position (n, 3) and (rho, satellite clock, sigma, elevation,
    C/N0, common sigma) (n, 6) of either input form; NaN wherever a value is malformed, so that the bounds
    reject its row. Columns of inconsistent shapes are malformed as a whole: every row is NaN."""
    if isinstance(prs, PseudorangeColumns):
        try:
            ids: list[object] = list(prs.sats)
        except TypeError:
            return [None], np.full((1, 3), np.nan), np.full((1, 6), np.nan)  # one reject
        n = len(ids)
        try:
            with np.errstate(invalid="ignore"):
                sats = np.array(prs.sat_pos_m, dtype=float).reshape(n, 3)
                common = prs.common_sigma_m if prs.common_sigma_m is not None else np.full(n, np.nan)
                num = np.column_stack(
                    [
                        np.asarray(c, dtype=float).reshape(n)
                        for c in (
                            prs.rho_m,
                            prs.sat_clock_s,
                            prs.sigma_m,
                            prs.elevation_rad,
                            prs.cn0_dbhz,
                            common,
                        )
                    ]
                ).reshape(n, 6)
        except (TypeError, ValueError, AttributeError, OverflowError):
            return ids, np.full((n, 3), np.nan), np.full((n, 6), np.nan)
        return ids, sats, num
    rows = cast(Sequence[PseudorangeObs], prs)
    n = len(rows)
    sats = np.full((n, 3), np.nan)
    num = np.full((n, 6), np.nan)  # rho, satellite clock, sigma, elevation, C/N0, common sigma
    try:
        sats[:] = [o.sat_pos_m for o in rows]
        num[:] = [
            (o.rho_m, o.sat_clock_s, o.sigma_m, o.elevation_rad, o.cn0_dbhz, o.common_sigma_m) for o in rows
        ]
    except (TypeError, ValueError, AttributeError, OverflowError):  # a malformed one: one by one
        for i, o in enumerate(rows):
            v = finite_vec3(getattr(o, "sat_pos_m", None))
            if v is not None:
                sats[i] = v
            num[i] = [
                x if (x := finite(getattr(o, name, None))) is not None else np.nan
                for name in ("rho_m", "sat_clock_s", "sigma_m", "elevation_rad", "cn0_dbhz", "common_sigma_m")
            ]
    return [getattr(o, "sat", None) for o in rows], sats, num


def _valid_plane(plane: PlaneObs | None, rejected: Counter[str]) -> PlaneObs | None:
    if plane is None:
        return None
    n = finite_vec3(getattr(plane, "normal", None))
    d = finite(getattr(plane, "d_m", None))
    sg = finite(getattr(plane, "sigma_m", None))
    if (
        n is None
        or d is None
        or sg is None
        or not (0.0 < sg <= MAX_PLANE_SIGMA_M)
        or abs(norm3(n) - 1.0) > MAX_NORMAL_ERROR
    ):
        rejected["plane"] += 1
        return None
    return plane


def _valid_ranges(epoch: EpochInput, rejected: Counter[str]) -> list[ValidRange]:
    """One range per pair (the first), a < b, sorted; malformed ones and repeats counted."""
    out: dict[tuple[str, str], ValidRange] = {}
    seen: set[tuple[str, str]] = set()
    for r in epoch.ranges or ():
        a, b = getattr(r, "a", None), getattr(r, "b", None)
        rng = finite(getattr(r, "range_m", None))
        if (
            not isinstance(a, str)
            or not isinstance(b, str)
            or a == b
            or rng is None
            or not 0 < rng <= MAX_RANGE_M
        ):
            rejected["range"] += 1
            continue
        pair = (a, b) if a < b else (b, a)
        if pair in seen:
            rejected["range"] += 1  # a pair at most once per epoch
            continue
        seen.add(pair)
        sg = finite(getattr(r, "sigma_m", None))
        usable = sg is not None and 0.0 < sg <= MAX_RANGE_SIGMA_M
        out[pair] = ValidRange(pair[0], pair[1], rng, sg if usable and sg is not None else math.nan)
    return [out[p] for p in sorted(out)]


def skipped_epoch(epoch: EpochInput, last: GpsTime | None, reason: str, solve_time_s: float) -> FleetSolution:
    """The solution of an epoch an estimator refuses as a whole (out of order or malformed)."""
    try:
        vids = sorted(epoch.vehicles)
    except Exception:  # untrusted input
        vids = []
    return FleetSolution(
        getattr(epoch, "time", last) or GpsTime(0, 0.0),
        {},
        solve_time_s,
        {},
        skipped={v: reason for v in vids},
        rejected={"epoch": 1},
    )
