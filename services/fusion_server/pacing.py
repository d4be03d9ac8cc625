"""When the fusion server solves an epoch: its pacing (lockstep or realtime), as a mixin of
`FusionServer` (docs/bus.md, "Paces").

Lockstep waits for every live vehicle it solves (with regions: those `RegionRole.awaited` names),
once per silent one; realtime solves `deadline_s` after an epoch's first message and never ahead
of the fleet's current epoch. Kept apart from `server.py` (what comes in and goes out) because it
is the part that decides timing, and reads the server's state only.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

from coplane.gtime import GpsTime
from coplane.messages import NodeMessage

from .admission import Admission
from .regions import RegionRole
from .settings import FusionSettings

log = logging.getLogger("coplane.fusion_server")

LINKED_WAIT_S = 2.0  # lockstep: how long a vehicle of another server's region, near ours, is awaited


class Pacing:
    """The scheduling half of `FusionServer` (which sets these fields)."""

    s: FusionSettings
    pending: dict[GpsTime, dict[str, NodeMessage]]
    first_arrival: dict[GpsTime, float]
    last_arrival: dict[GpsTime, float]
    latest: dict[str, GpsTime]
    solved_up_to: GpsTime | None
    live: set[str]
    known: set[str]
    started: float
    waiting_since: float | None
    admission: Admission
    regions: RegionRole | None
    _reject: Callable[[str | None, str, str], None]

    def ready_epoch(self, now: float) -> GpsTime | None:
        """The next epoch to solve now, or None.

        Realtime never solves an epoch ahead of the fleet's current epoch (`Admission.solve_limit`):
        a message ahead of the fleet waits for it instead of making the fleet's epochs late. Lockstep
        waits for each silent live vehicle once (`stall_timeout_s`), then not again until it sends."""
        self._drop_outside_window(now)
        if self.regions is not None and now - self.started >= self.s.startup_wait_s:
            self.regions.start_anyway()
        if not self.pending or self._start_wait(now):
            return None
        t = min(self.pending)
        if self.s.pace == "realtime":
            limit = self.admission.solve_limit(now, self.solved_up_to)
            if limit is not None and limit < t:
                return None
            return t if now - self.first_arrival[t] >= self.s.deadline_s else None
        if not self._fleet_waited(now) and not self.known <= self.live:
            return None  # lockstep start: give every agent the chance to show up
        if not self._own_vehicle_waiting(t):
            here = self._live_here(self.pending[t], t)
            if not any(self._awaits(v, t) for v in here) or self._only_linked_overdue(here, t, now):
                self.waiting_since = None
                return t
        if self.waiting_since is None:
            self.waiting_since = now
        if now - self.waiting_since > self.s.stall_timeout_s:
            waiting = [v for v in self._live_here(self.pending[t], t) if self._awaits(v, t)]
            log.warning("solving without silent vehicles", extra={"vehicles": ",".join(sorted(waiting))})
            self.admission.mark_silent(waiting)  # e.g. a token without an agent: wait once, not every epoch
            self.waiting_since = None
            return t
        return None

    def _awaits(self, v: str, t: GpsTime) -> bool:
        """Whether lockstep still waits for live vehicle `v` at epoch `t`: not heard at `t` or
        later, and not given up on as silent. Asked per vehicle and stopped at the first waiting
        one (`ready_epoch` runs after every message: a list of all of them each time cost
        O(vehicles^2) per epoch)."""
        return (v not in self.latest or self.latest[v] < t) and not self.admission.is_silent(v)

    def _own_vehicle_waiting(self, t: GpsTime) -> bool:
        """Regions: a vehicle of this server's own regions is still awaited at `t`, so the epoch
        is not ready whatever `RegionRole.awaited` would add (the cheap answer while an epoch comes
        in; the full set is built only once none of them is left)."""
        regions = self.regions
        return regions is not None and any(
            self._awaits(v, t) and regions.surely_awaited(v, t) for v in self.live
        )

    def _only_linked_overdue(self, here: set[str], t: GpsTime, now: float) -> bool:
        """Regions: every vehicle still awaited is in another server's region (linked by ranges to
        this server's, or heard here lately), and no message of the epoch came for
        `LINKED_WAIT_S`: solve without them (their message may go only to their own server now).
        From the epoch's latest message, not its first: one load generator puts a 256-vehicle
        epoch over about 2 s, and a vehicle crossing into this server's regions late in that
        order was given up on before its message came (its epoch then went unanswered)."""
        if self.regions is None or now - self.last_arrival.get(t, now) < LINKED_WAIT_S:
            return False
        return not self.regions.owned_vehicles([v for v in here if self._awaits(v, t)])

    def _live_here(
        self, upcoming: dict[str, NodeMessage] | None = None, t: GpsTime | None = None
    ) -> set[str]:
        """The live vehicles this server solves: all of them, or with regions those it may solve
        (`RegionRole.awaited`)."""
        if self.regions is None:
            return self.live
        return self.regions.awaited(self.live, upcoming or {}, t, self.admission.config.interval_s)

    def _fleet_waited(self, now: float) -> bool:
        """Whether the start has waited `startup_wait_s` for the fleet, counted from its first
        admitted message, not from the server's start: a server started long before its fleet,
        or a load generator that takes seconds to put the first epoch of 1000 vehicles, must not
        have spent its patience before anyone spoke (the latecomers of the first epoch were then
        late, and at 1000 vehicles a whole epoch went unanswered)."""
        first = self.admission.first_admit_s
        return first is not None and now - max(first, self.started) >= self.s.startup_wait_s

    def _start_wait(self, now: float) -> bool:
        """Start (nothing solved, no resume): wait until every vehicle of the recording has been
        admitted, or `startup_wait_s`, so a lone first sender (its epoch could be a week ahead or
        behind) is not taken for the fleet. A fast realtime replay with a vehicle that never speaks
        stops waiting once two vehicles have spoken and half the pending bound is used, before
        genuine epochs are refused."""
        if self.solved_up_to is not None or self._fleet_waited(now):
            return False
        if self.regions is not None:  # the other servers' vehicles never speak to this one
            return not self.regions.settled(now, self.live)
        spoke = set(self.latest)
        if self.known <= spoke:
            return False
        return not (len(spoke) >= 2 and len(self.pending) >= self.admission.config.pending_limit // 2)

    def _drop_outside_window(self, now: float) -> None:
        """Drop pending epochs outside the window of the fleet's current epoch (admitted before the
        fleet's epoch was known, e.g. from a lone first sender): they would never be solved, or be
        solved as a stray epoch far from the fleet's. Their messages are counted rejected
        (too-far-ahead / too-far-behind), so the counters still add up."""
        while self.pending:
            side = None
            for t in (max(self.pending), min(self.pending)):
                if (side := self.admission.outside_window(t, now, self.solved_up_to)) is not None:
                    break
            if side is None:
                return
            msgs = self.pending.pop(t)
            log.debug("epoch dropped", extra={"epoch": str(t), "messages": len(msgs), "side": side})
            self.first_arrival.pop(t, None)
            self.last_arrival.pop(t, None)
            self.admission.forget(t)
            for vid in msgs:
                self._reject(vid, side, f"epoch {t} dropped from pending")
