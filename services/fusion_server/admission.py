"""What the fusion server lets into an epoch: the policy against valid but hostile node messages.

A node message that passed the wire model (`coplane.messages`) is well formed, yet it can still
freeze or poison the fleet: an epoch a week ahead makes every genuine epoch "late", thousands of
distinct epochs fill memory, a plane with offset 1e4 m and sigma 1 cm moves a vehicle by
thousands of kilometres, and a second, different message for an epoch could displace the genuine
one. `Admission` decides, before anything enters the server's `pending`, whether a message is
admitted, late, a duplicate or rejected (and why), and which epochs the server may solve. It is
pure policy: no I/O, no clock (callers pass `now`, monotonic seconds), so every rule is unit-tested
(tests/fusion_server/test_admission.py). The rules, their defaults and why: docs/bus.md, Admission.

Genuine maxima measured by `tests/fusion_server/test_admission.py` on the bundled recording (4
vehicles x 600 epochs, pc), the real data (Nagoya static, UrbanNav HK TST static, HK Kowloon Tong
rover) and a simulated dense-urban fleet (4 x 300 epochs) are in `GENUINE_MAX`; every threshold
below is several times above them, so 0 genuine messages are rejected.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from coplane.geo import WGS84_A, ecef_to_geodetic, up_vector
from coplane.gnss.constants import C
from coplane.gtime import GpsTime
from coplane.messages import NodeMessage, PlaneReport

# Genuine maxima (see the module docstring; re-measured by the tests, which fail if they grow past
# half of a threshold): the worst SPP fix's median |residual| after removing each system's clock,
# its ellipsoidal height range, the worst plane tilt from the local up and the worst SPP-to-plane
# distance.
GENUINE_MAX = {
    "spp_residual_m": 3.8,  # HK Kowloon Tong rover (urban, F9P); simulated: 1.4 (dense urban)
    "spp_height_m": (-33.1, 114.9),  # simulated dense urban (SPP vertical error); real: -2.6..105.7
    "plane_tilt_deg": 8.0,  # bundled recording (its roads' grade plus the fit's tilt)
    "plane_distance_m": 38.0,  # simulated dense urban (SPP's vertical error in the canyon)
}

# A road vehicle's antenna, ellipsoidal height: the Dead Sea shore (-430 m) to the highest roads
# (about 5,800 m), with room for an SPP fix's vertical error; the same band as the consumers'
# check of solved positions (coplane.bus.trust).
SPP_HEIGHT_M = (-1_000.0, 10_000.0)
# SPP self-consistency: median |pseudorange residual| (each system's clock removed) of the used
# satellites at the reported fix: 6.5x the genuine maximum (GENUINE_MAX). Measured on the bundled
# recording, a fix displaced by 300 m gives 20..100 m (median over epochs and directions 100 m),
# by 1 km 71..340 m: every displacement above ~400 m is caught, most above ~80 m. A displaced SPP
# fix is only the estimator's initial guess (the pseudoranges decide), so the margin goes to
# never rejecting a genuine fix.
SPP_RESIDUAL_M = 25.0
MIN_SATS_FOR_RESIDUAL = 5  # fewer used satellites cannot show a displaced fix (4 unknowns + 1)
# Road planes: the steepest public roads are ~35 % (19 degrees); the plane is fitted in the
# vehicle's frame with its own tilt error on top.
PLANE_TILT_DEG = 30.0
# SPP-to-plane distance at the antenna: SPP's vertical error in urban canyons is tens of metres,
# so the bound is loose (4x the genuine maximum); it catches planes that would pull the vehicle
# far off (the 1e4 m offset of issue 13) and bounds what a plausible-looking forged plane can do.
PLANE_DISTANCE_M = 150.0
# A plane near the surface has |d| (d = -n.p for p on the plane) between the smallest Earth radius
# plus the lowest height, times cos of the largest tilt, and the largest radius plus the highest.
_MIN_RADIUS_M = WGS84_A * (1.0 - 1.0 / 298.257223563) + SPP_HEIGHT_M[0]
_MAX_PLANE_D_M = WGS84_A + SPP_HEIGHT_M[1]
HISTORY_DEPTH = 120  # node messages an agent's publication cache replays to a restarted server

Outcome = Literal["admit", "late", "duplicate", "reject"]


@dataclass(frozen=True)
class AdmissionConfig:
    """The thresholds (FusionSettings gives them; defaults and why in docs/bus.md, Admission)."""

    interval_s: float = 1.0
    grid_tolerance_s: float = 1e-3  # agents stamp nominal epochs: exact multiples of the interval
    max_ahead_s: float = 30.0
    max_pending_epochs: int = 0  # 0: derived (`pending_limit`)
    rate_per_s: float = 5.0
    rate_per_epoch: float = 3.0
    burst: float = 2 * HISTORY_DEPTH
    silent_after_s: float = 5.0
    spp_residual_m: float = SPP_RESIDUAL_M
    plane_tilt_deg: float = PLANE_TILT_DEG
    plane_distance_m: float = PLANE_DISTANCE_M
    # "reject": a message whose plane contradicts it is hostile as a whole (the rest of it, e.g.
    # its ranges to genuine vehicles, would still move them); "drop": use it without the plane.
    plane_policy: Literal["reject", "drop"] = "reject"

    @property
    def max_behind_s(self) -> float:
        """How far behind the fleet's current epoch an epoch may be: what an agent's cache replays
        to a restarted server (`HISTORY_DEPTH` epochs), plus the window's margin again."""
        return self.max_ahead_s + HISTORY_DEPTH * self.interval_s

    @property
    def pending_limit(self) -> int:
        """Epochs that may wait: the window ahead, plus what a restarted server's history replay
        brings at once (`HISTORY_DEPTH` epochs behind), plus a margin."""
        if self.max_pending_epochs > 0:
            return self.max_pending_epochs
        return math.ceil(self.max_ahead_s / self.interval_s) + HISTORY_DEPTH + 16


@dataclass(frozen=True)
class Verdict:
    """What to do with one message: `message` is what to admit (its plane may have been dropped)."""

    outcome: Outcome
    reason: str = ""  # why it was rejected, a short kind ("" otherwise)
    message: NodeMessage | None = None
    detail: str = ""  # for the log: the numbers behind a rejection or a dropped plane
    plane_dropped: bool = False


@dataclass
class TokenBucket:
    """Per-vehicle rate limit: refilled per wall second and per solved epoch, capped at `burst`."""

    tokens: float
    stamp: float

    def take(self, now: float, rate_per_s: float, burst: float) -> bool:
        """Refill for the time since the last call, then spend one token if there is one."""
        self.tokens = min(burst, self.tokens + max(0.0, now - self.stamp) * rate_per_s)
        self.stamp = now
        if self.tokens >= 1.0:
            self.tokens -= 1.0
            return True
        return False


@dataclass
class VehicleState:
    """What admission remembers of one vehicle (bounded: known vehicles only)."""

    bucket: TokenBucket
    latest: GpsTime | None = None  # latest admitted epoch
    first: GpsTime | None = None  # earliest admitted epoch (the start: where this vehicle began)
    latest_seq: int | None = None  # its seq
    last_admit_s: float | None = None  # when a message was last admitted
    silent: bool = False  # lockstep stopped waiting for it; cleared by its next admitted message


@dataclass
class Admission:
    """The admission state of one server: per-vehicle buckets and sequence, pending digests."""

    config: AdmissionConfig
    vehicles: dict[str, VehicleState] = field(default_factory=dict)
    digests: dict[GpsTime, dict[str, bytes]] = field(default_factory=dict)  # pending (epoch, vehicle)
    min_tokens: float = math.inf  # lowest bucket level a message left (measured in the tests)

    def _vehicle(self, vid: str, now: float) -> VehicleState:
        v = self.vehicles.get(vid)
        if v is None:
            v = self.vehicles[vid] = VehicleState(TokenBucket(self.config.burst, now))
        return v

    # -- the fleet's current epoch -----------------------------------------------------------
    def active(self, now: float) -> dict[str, GpsTime]:
        """Latest admitted epoch of each vehicle that admitted a message lately (`silent_after_s`):
        a vehicle that stopped sending does not hold the reference back."""
        lim = self.config.silent_after_s
        return {
            vid: v.latest
            for vid, v in self.vehicles.items()
            if v.latest is not None and v.last_admit_s is not None and now - v.last_admit_s <= lim
        }

    def reference(
        self, now: float, solved_up_to: GpsTime | None, exclude: str | None = None, upper: bool = False
    ) -> GpsTime | None:
        """The fleet's current epoch: the lower median of the active vehicles' latest epochs (one
        vehicle far ahead cannot raise it; `upper`: the upper median, which one vehicle far behind
        cannot lower), never below the last solved epoch; None if no vehicle (other than
        `exclude`) is active."""
        lat = sorted(t for vid, t in self.active(now).items() if vid != exclude)
        if not lat:
            return None
        med = lat[len(lat) // 2] if upper else lat[(len(lat) - 1) // 2]
        return med if solved_up_to is None or solved_up_to < med else solved_up_to

    def solve_limit(self, now: float, solved_up_to: GpsTime | None) -> GpsTime | None:
        """The last epoch the realtime pace may solve now: the fleet's current epoch, so a message
        ahead of the fleet waits for the fleet instead of making its epochs late. With no active
        vehicle (start, end of a run), the window after the last solved epoch; None: no bound."""
        ref = self.reference(now, solved_up_to)
        if ref is not None:
            return ref
        return solved_up_to + self.config.max_ahead_s if solved_up_to is not None else None

    def outside_window(self, t: GpsTime, now: float, solved_up_to: GpsTime | None) -> str | None:
        """Whether a pending epoch lies outside the window of the fleet's current epoch, and on
        which side (the server drops such epochs, admitted before the fleet's epoch was known:
        they would never be solved, or solved as a stray epoch long before the fleet's).

        Ahead: of the lower median, once an epoch was solved (the reference is then never below
        it, so a vehicle far behind cannot pull it down) or with three active vehicles. Behind (of
        the upper median): only before the first solve, with three active vehicles; afterwards an
        epoch behind is late or between the last solved epoch and the fleet's (a resume's replay).
        Two vehicles that disagree at the start cannot be told apart: nothing is dropped."""
        tol = self.config.grid_tolerance_s
        n = len(self.active(now))
        if solved_up_to is not None or n >= 3:
            ref = self.reference(now, solved_up_to)
            if ref is not None and t - ref > self.config.max_ahead_s + tol:
                return "too-far-ahead"
        if solved_up_to is None and n >= 3:
            ref = self.reference(now, None, upper=True)
            if ref is not None and ref - t > self.config.max_behind_s + tol:
                return "too-far-behind"
            start = self.fleet_start(now)
            if start is not None and start - t > self.config.max_ahead_s + tol:
                return "too-far-behind"  # before where the fleet began: a stray first epoch
        return None

    def fleet_start(self, now: float) -> GpsTime | None:
        """Where the fleet began: the lower median of the active vehicles' earliest admitted
        epochs (a history replay after a restart included), so one vehicle's stray old epoch is
        not solved first."""
        active = self.active(now)
        firsts = sorted(v.first for vid, v in self.vehicles.items() if v.first is not None and vid in active)
        return firsts[(len(firsts) - 1) // 2] if firsts else None

    # -- one message ---------------------------------------------------------------------------
    def check(
        self,
        msg: NodeMessage,
        t: GpsTime,
        digest: bytes,
        now: float,
        *,
        solved_up_to: GpsTime | None,
        pending_epochs: int,
        epoch_pending: bool,
    ) -> Verdict:
        """The verdict on a decoded message of a known vehicle (key, fleet already checked).

        Order: rate (every decoded message costs), grid, late, duplicate/conflict, sequence,
        window, pending bound, plausibility. Call `admitted` when the server admits it."""
        cfg = self.config
        vid = msg.vehicle_id
        v = self._vehicle(vid, now)
        if not v.bucket.take(now, cfg.rate_per_s, cfg.burst):
            return Verdict("reject", "rate-limited")
        self.min_tokens = min(self.min_tokens, v.bucket.tokens)
        if abs(t - t.round_to(cfg.interval_s)) > cfg.grid_tolerance_s:
            return Verdict("reject", "off-grid")
        if solved_up_to is not None and not solved_up_to < t:
            return Verdict("late")  # not evidence of life for lockstep: anyone can send an old epoch
        prior = self.digests.get(t, {}).get(vid)
        if prior is not None:
            if prior != digest:
                return Verdict("reject", "conflict")
            v.last_admit_s = now  # a lockstep agent waiting for its solution is still active
            return Verdict("duplicate")
        # ahead of the others' current epoch: only once an epoch was solved (before, one vehicle
        # far behind could make a genuine epoch look ahead; `outside_window` cleans up the start)
        ref = self.reference(now, solved_up_to, exclude=vid) if solved_up_to is not None else None
        if ref is not None and t - ref > cfg.max_ahead_s + cfg.grid_tolerance_s:
            return Verdict(
                "reject", "too-far-ahead", detail=f"epoch {t} is {t - ref:.0f} s after the fleet's {ref}"
            )
        if v.last_admit_s is not None and now - v.last_admit_s > cfg.silent_after_s:
            v.latest_seq = None  # silent that long: its agent may have restarted (seq from 0)
        if not self._seq_consistent(v, msg.seq, t):
            return Verdict(
                "reject",
                "replay",
                detail=f"seq {msg.seq} at epoch {t} after seq {v.latest_seq} at {v.latest}",
            )
        if not epoch_pending and pending_epochs >= cfg.pending_limit:
            return Verdict("reject", "pending-full")
        if (why := spp_problem(msg, cfg.spp_residual_m)) is not None:
            return Verdict("reject", "implausible-spp", detail=why)
        if msg.plane is not None and (why := plane_problem(msg, cfg.plane_tilt_deg, cfg.plane_distance_m)):
            if cfg.plane_policy == "reject":
                return Verdict("reject", "implausible-plane", detail=why)
            dropped = PlaneReport(status="unavailable", reason=f"dropped by the fusion server: {why}")
            return Verdict(
                "admit", message=msg.model_copy(update={"plane": dropped}), detail=why, plane_dropped=True
            )
        return Verdict("admit", message=msg)

    def _seq_consistent(self, v: VehicleState, seq: int, t: GpsTime) -> bool:
        """A genuine agent counts one seq per epoch it processes (a realtime agent skips epochs
        without counting), so seq and epoch move together: a later epoch has a greater seq, by at
        most the epochs between them, and an earlier one (a history replay) a smaller seq."""
        if v.latest is None or v.latest_seq is None:
            return True  # first message, or reset (liveliness lost, silent): an agent restarts at 0
        k = round((t - v.latest) / self.config.interval_s)
        if seq == 0 and k > 0:
            return True  # a restarted agent, before its old liveliness token has expired
        ds = seq - v.latest_seq
        return 1 <= ds <= k if k > 0 else k <= ds <= -1

    def admitted(self, vid: str, t: GpsTime, seq: int, digest: bytes, now: float) -> None:
        """Record an admitted message: its digest (duplicates), the vehicle's latest epoch and seq."""
        v = self._vehicle(vid, now)
        self.digests.setdefault(t, {})[vid] = digest
        if v.latest is None or v.latest < t:
            v.latest, v.latest_seq = t, seq
        if v.first is None or t < v.first:
            v.first = t
        v.last_admit_s = now
        v.silent = False

    # -- server events -------------------------------------------------------------------------
    def solved(self, t: GpsTime) -> None:
        """An epoch was solved (or dropped): forget its digests, and give every vehicle the tokens
        of one epoch (a lockstep fleet runs as fast as the solver: its rate is per epoch)."""
        self.digests.pop(t, None)
        for v in self.vehicles.values():
            v.bucket.tokens = min(self.config.burst, v.bucket.tokens + self.config.rate_per_epoch)

    def offline(self, vid: str) -> None:
        """The vehicle's liveliness token went away: its agent may restart with seq 0."""
        v = self.vehicles.get(vid)
        if v is not None:
            v.latest = v.latest_seq = v.last_admit_s = v.first = None
            v.silent = False

    def forget(self, t: GpsTime) -> None:
        """An epoch was dropped unsolved: forget its digests."""
        self.digests.pop(t, None)

    def mark_silent(self, vids: set[str] | list[str]) -> None:
        """Lockstep gave up waiting for these live vehicles: do not wait again until they send."""
        for vid in vids:
            if vid in self.vehicles:
                self.vehicles[vid].silent = True
            else:
                self.vehicles[vid] = VehicleState(TokenBucket(self.config.burst, 0.0), silent=True)

    def is_silent(self, vid: str) -> bool:
        v = self.vehicles.get(vid)
        return v is not None and v.silent


# -- plausibility against the message's own measurements ----------------------------------------
def spp_residual_m(msg: NodeMessage) -> float | None:
    """Median |pseudorange residual| of the used satellites at the reported SPP fix, each system's
    clock removed by its median (robust to NLOS outliers); None when it cannot tell (no fix, too
    few satellites)."""
    p = msg.spp.position_ecef_m
    used = [s for s in msg.satellites if s.used]
    if p is None or len(used) < MIN_SATS_FOR_RESIDUAL:
        return None
    pos = np.asarray(p, dtype=float)
    sat = np.array([s.sat_pos_ecef_m for s in used], dtype=float)
    rho = np.array([s.rho_m + C * s.sat_clock_s for s in used], dtype=float)
    res = rho - np.linalg.norm(sat - pos, axis=1)
    systems = np.array([s.sat[0] for s in used])
    for sys in set(systems.tolist()):
        m = systems == sys
        res[m] -= np.median(res[m])
    return float(np.median(np.abs(res)))


def spp_height_m(msg: NodeMessage) -> float | None:
    """Ellipsoidal height of the reported SPP position, if any."""
    p = msg.spp.position_ecef_m
    return None if p is None else float(ecef_to_geodetic(np.asarray(p, dtype=float))[2])


def spp_problem(msg: NodeMessage, max_residual_m: float) -> str | None:
    """Why the message's SPP position is implausible (off the Earth's surface, or not where its
    own pseudoranges put it), or None."""
    h = spp_height_m(msg)
    if h is not None and not SPP_HEIGHT_M[0] <= h <= SPP_HEIGHT_M[1]:
        return f"SPP height {h:.0f} m is outside {SPP_HEIGHT_M[0]:.0f}..{SPP_HEIGHT_M[1]:.0f} m"
    if msg.spp.ok:
        r = spp_residual_m(msg)
        if r is not None and r > max_residual_m:
            return f"SPP fix is {r:.0f} m (median residual) from its own pseudoranges"
    return None


def plane_tilt_deg(plane: PlaneReport, at: tuple[float, float, float]) -> float:
    """Angle between the plane's normal and the local geodetic up at `at`."""
    n = np.asarray(plane.normal, dtype=float)
    c = float(np.clip(np.dot(n, up_vector(np.asarray(at, dtype=float))), -1.0, 1.0))
    return math.degrees(math.acos(c))


def plane_distance_m(plane: PlaneReport, at: tuple[float, float, float]) -> float:
    """Signed distance of `at` from the plane (n.p + d, positive above)."""
    assert plane.normal is not None and plane.d_antenna_m is not None
    return float(
        np.dot(np.asarray(plane.normal, dtype=float), np.asarray(at, dtype=float)) + plane.d_antenna_m
    )


def plane_problem(msg: NodeMessage, max_tilt_deg: float, max_distance_m: float) -> str | None:
    """Why the message's plane is implausible, or None. Its offset must put it near the Earth's
    surface; against the SPP fix and against the plane's own centroid (whichever are reported;
    genuine planes always have a centroid), the normal must be near the local up and the point
    near the plane. A plane with neither cannot be checked and is implausible."""
    pl = msg.plane
    if pl is None or pl.status == "unavailable" or pl.normal is None or pl.d_antenna_m is None:
        return None
    if not _MIN_RADIUS_M * math.cos(math.radians(max_tilt_deg)) <= abs(pl.d_antenna_m) <= _MAX_PLANE_D_M:
        return f"plane offset {pl.d_antenna_m:.0f} m does not put it near the Earth's surface"
    refs = [
        (what, p) for what, p in (("SPP fix", msg.spp.position_ecef_m), ("centroid", pl.centroid_ecef_m)) if p
    ]
    if not refs:
        return "plane has neither an SPP fix nor a centroid to check it against"
    for what, p in refs:
        h = float(ecef_to_geodetic(np.asarray(p, dtype=float))[2])
        if not SPP_HEIGHT_M[0] <= h <= SPP_HEIGHT_M[1]:
            return f"plane {what} height {h:.0f} m is off the Earth's surface"
        tilt = plane_tilt_deg(pl, p)
        if tilt > max_tilt_deg:
            return f"plane normal is {tilt:.1f} deg from the local up at the {what}"
        dist = plane_distance_m(pl, p)
        if abs(dist) > max_distance_m:
            return f"the {what} is {dist:.0f} m from the plane"
    return None
