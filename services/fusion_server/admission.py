"""What the fusion server lets into an epoch: the policy against valid but hostile node messages.

A node message that passed the wire model (`coplane.messages`) is well formed, yet it can still
freeze or poison the fleet: an epoch a week ahead makes every genuine epoch "late", thousands of
distinct epochs fill memory, a plane with offset 1e4 m and sigma 1 cm moves a vehicle by
thousands of kilometres, and a second, different message for an epoch could displace the genuine
one. `Admission` decides, before anything enters the server's `pending`, whether a message is
admitted, late, a duplicate or rejected (and why), and which epochs the server may solve. It is
pure policy: no I/O, no clock (callers pass `now`, monotonic seconds), so every rule is unit-tested
(tests/fusion_server/test_admission.py). The rules, their defaults and why: docs/bus.md, Admission.

The plausibility checks of a message against its own measurements (SPP fix, road plane) and the
genuine maxima behind their thresholds are in `plausibility.py`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

from coplane.gtime import GpsTime
from coplane.messages import NodeMessage, PlaneReport

from .fleet_epoch import FleetEpochs
from .plausibility import PLANE_DISTANCE_M, PLANE_TILT_DEG, SPP_RESIDUAL_M, plane_problem, spp_problem

HISTORY_DEPTH = 120  # node messages an agent's publication cache replays to a restarted server
USED_DIGEST_EPOCHS = 8  # solved epochs whose used messages' digests are kept (re-sends: duplicate)
MAX_PACE = 100.0  # epoch seconds per wall second a fleet may advance (realtime `speed`; consumers alike)


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
    last_admit_s: float | None = None  # when a message was last admitted (or re-sent)
    seen_s: float | None = None  # the same, but kept when it goes offline (how long the fleet is quiet)
    silent: bool = False  # lockstep stopped waiting for it; cleared by its next admitted message


@dataclass
class Admission:
    """The admission state of one server: per-vehicle buckets and sequence, pending digests."""

    config: AdmissionConfig
    vehicles: dict[str, VehicleState] = field(default_factory=dict)
    digests: dict[GpsTime, dict[str, bytes]] = field(default_factory=dict)  # pending (epoch, vehicle)
    # the last solved epochs' digests: a lockstep agent's re-send that crossed the solution is a
    # duplicate of what the solve used, not a late message (its data did not miss the epoch)
    used_digests: dict[GpsTime, dict[str, bytes]] = field(default_factory=dict)
    min_tokens: float = math.inf  # lowest bucket level a message left (measured in the tests)
    first_admit_s: float | None = None  # when the first message was admitted: the fleet's start
    epochs: FleetEpochs = field(init=False)  # the active vehicles' latest epochs, kept as they change

    def __post_init__(self) -> None:
        self.epochs = FleetEpochs(self.config.silent_after_s)

    def _changed(self, vid: str, v: VehicleState) -> None:
        """A vehicle's latest epoch or admit time changed: keep `epochs` in step."""
        self.epochs.update(vid, v.latest, v.last_admit_s, v.first)

    def _vehicle(self, vid: str, now: float) -> VehicleState:
        v = self.vehicles.get(vid)
        if v is None:
            v = self.vehicles[vid] = VehicleState(TokenBucket(self.config.burst, now))
        return v

    # -- the fleet's current epoch -----------------------------------------------------------
    def active(self, now: float) -> dict[str, GpsTime]:
        """Latest admitted epoch of each vehicle that admitted a message lately (`silent_after_s`):
        a vehicle that stopped sending does not hold the reference back."""
        return self.epochs.active(now)

    def reference(
        self, now: float, solved_up_to: GpsTime | None, exclude: str | None = None, upper: bool = False
    ) -> GpsTime | None:
        """The fleet's current epoch: the lower median of the active vehicles' latest epochs (one
        vehicle far ahead cannot raise it; `upper`: the upper median, which one vehicle far behind
        cannot lower), never below the last solved epoch; None if no vehicle (other than
        `exclude`) is active."""
        med = self.epochs.median(now, exclude=exclude, upper=upper)
        if med is None:
            return None
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
        n = self.epochs.count(now)
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
        return self.epochs.first_median(now)

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
            if self.used_digests.get(t, {}).get(vid) == digest:
                return Verdict("duplicate")  # a re-send of what the solve used
            return Verdict("late")  # not evidence of life for lockstep: anyone can send an old epoch
        prior = self.digests.get(t, {}).get(vid)
        if prior is not None:
            if prior != digest:
                return Verdict("reject", "conflict")
            v.last_admit_s = v.seen_s = now  # a lockstep agent waiting for its solution is still active
            self._changed(vid, v)
            return Verdict("duplicate")
        # ahead of the others' current epoch: only once an epoch was solved (before, one vehicle
        # far behind could make a genuine epoch look ahead; `outside_window` cleans up the start)
        if solved_up_to is not None and (why := self._too_far_ahead(vid, t, now, solved_up_to)):
            return Verdict("reject", "too-far-ahead", detail=why)
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

    def _too_far_ahead(self, vid: str, t: GpsTime, now: float, solved_up_to: GpsTime) -> str | None:
        """Why `t` is too far ahead of the other vehicles' current epoch, or None. A vehicle alone
        (the others quiet or gone) is bounded by the last solved epoch plus what the fleet could
        have advanced since the others were last heard (`MAX_PACE`), so it can rejoin after a gap
        but cannot jump a week while the fleet pauses; with no other vehicle ever heard (a
        single-vehicle fleet, a resume) it is its own reference."""
        tol = self.config.grid_tolerance_s
        ref = self.reference(now, solved_up_to, exclude=vid)
        if ref is not None:
            limit = self.config.max_ahead_s
        else:
            heard = [v.seen_s for other, v in self.vehicles.items() if other != vid and v.seen_s is not None]
            if not heard:
                return None
            ref, limit = solved_up_to, self.config.max_ahead_s + MAX_PACE * max(0.0, now - max(heard))
        if t - ref > limit + tol:
            return f"epoch {t} is {t - ref:.0f} s after the fleet's {ref} (at most {limit:.0f} s)"
        return None

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
        if self.first_admit_s is None:
            self.first_admit_s = now
        self.digests.setdefault(t, {})[vid] = digest
        if v.latest is None or v.latest < t:
            v.latest, v.latest_seq = t, seq
        if v.first is None or t < v.first:
            v.first = t
        v.last_admit_s = v.seen_s = now
        v.silent = False
        self._changed(vid, v)

    # -- server events -------------------------------------------------------------------------
    def solved(self, t: GpsTime) -> None:
        """An epoch was solved: its digests move to `used_digests` (the last few epochs), and every
        vehicle gets the tokens of one epoch (a lockstep fleet runs as fast as the solver: its rate
        is per epoch)."""
        used = self.digests.pop(t, None)
        if used:
            self.used_digests[t] = used
            while len(self.used_digests) > USED_DIGEST_EPOCHS:
                del self.used_digests[min(self.used_digests)]
        for v in self.vehicles.values():
            v.bucket.tokens = min(self.config.burst, v.bucket.tokens + self.config.rate_per_epoch)

    def offline(self, vid: str) -> None:
        """The vehicle's liveliness token went away: its agent may restart with seq 0."""
        v = self.vehicles.get(vid)
        if v is not None:
            v.latest = v.latest_seq = v.last_admit_s = v.first = None
            v.silent = False
            self._changed(vid, v)

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
