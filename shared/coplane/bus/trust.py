"""`SolutionGate`: what a consumer (API, vehicle agent, `coplane fleet` collector) takes from the
fleet's `solution` key. One rule set, used by all three (docs/bus.md, "Consumers").

On a secure bus the router's ACL is the authority: only the fusion identity may put `solution`.
The gate is the defence in depth that also holds with `--insecure` and against a buggy server. It
cannot tell who sent a message (Zenoh's `Sample.source_info` is absent unless the publisher sets
it, and then it is whatever the publisher claims), so it checks that a message is *plausible as
the continuation of what was already accepted*:

Whole message rejected (reason counted):
  - `wrong-fleet`, `wrong-method`: not the fleet (or method, where the consumer knows it) it follows.
  - `off-earth`: a vehicle is not within `HEIGHT_BAND_M` of the ellipsoid (e.g. (0, 0, 0)). The
    server never publishes such a position, so the message is forged or the server is broken; a
    joint solve with one absurd vehicle is suspect as a whole, and keeping "the rest" would let a
    forger smuggle the other vehicles in.
  - `repeat` (same generation, same epoch: a resend, or the server's one republish after a resume)
    and `stale` (an older epoch of the same generation): a consumer's picture only moves forward.
    The genuine server never goes back within a generation, so if for `resync_s` wall seconds
    nothing was accepted while older epochs of it keep coming, the head we hold was a forgery (or
    a bug) that nobody continued: the consumer resets and follows the stream again.
  - `too-far-ahead`: more than `max_ahead_s + max_pace * (wall seconds since the last accepted)`
    ahead of the last accepted epoch. A fleet that pauses (lockstep agents waiting, realtime with
    no agent) does not advance its epochs, and a realtime fleet advances them with the wall clock,
    so only a recording gap longer than `max_ahead_s` needs the allowance to grow; a consumer that
    knows where the fleet is (a vehicle agent: its own current epoch) passes it as `expect`, and
    then a solution is too far ahead only if it is more than `max_ahead_s` beyond that epoch (also
    for its first one), so a recording gap can never stall a lockstep agent.
  - `new-generation`: another server run while the current one is not silent (see below).

One vehicle dropped (counted as `vehicle-unknown`, `vehicle-jump`, `too-many-vehicles`), the rest kept:
  - a vehicle not in the fleet's known set (the manifest, when the consumer has it);
  - a vehicle farther from its last accepted position (same generation) than
    `max_speed_mps * epoch gap + jump_margin_m`. A genuine estimator may re-initialise one vehicle
    from a poor fix, and lockstep agents must still receive the epoch, so only that vehicle goes;
  - a new vehicle once `max_vehicles` are remembered (bounded memory without a known set);
  - regions: a state that none of its server's regions reaches (`vehicle-not-owner`, checked by
    the set of gates, `coplane.bus.gates.GateSet`).
  If no vehicle of a non-empty message is left, the message is rejected (`no-trusted-vehicle`)
  without moving the epoch, so the genuine solution of that epoch is still taken. Likewise, once
  the run follows some vehicles, a message that continues none of them is rejected without moving
  the epoch: `empty` (no vehicle at all) or `no-continuing-vehicle` (only vehicles never seen in
  this run). The genuine server's solutions carry the fleet's tracked vehicles (its estimators
  carry a vehicle through outages), so only a forgery, or the first solution of a run, lacks them.

Generations: every solution names its server run (`SolutionMessage.generation`; the same after a
resume from the log, so a crash is not a new run). Only a different generation lets a consumer
reset. A forger on an insecure bus can invent one, so a new generation is adopted only once the
current run is over: its server withdrew its liveliness token (`server_gone`: a clean stop, a
crash, an expired lease), or it has been silent for `restart_quiet_s` wall seconds (a consumer
that does not follow the tokens, or a server replaced while its token stays up). A token cannot be
withdrawn by anyone but the session that declared it: Zenoh's router keeps a key alive while any
session declares it, so a forger's twin of the server's token going away changes nothing
(tests/bus/test_trust_tokens.py). So a restarted server is followed from its first solution,
and a forger's generation is refused while the genuine server is up. While the current run is
not over, an invented generation is rejected; the last such message is held, and `release(now)`
adopts it once the run is over, so a consumer that waits for exactly that message (a lockstep
agent) is not stalled by a fast restart; a held message the current run continued after is
dropped instead (a forgery: a successor's first solution comes after its predecessor's last).
Residual risk, insecure bus only: while the genuine server is down (or silent for longer than
`restart_quiet_s`), a forger can make consumers reset, and anyone can stamp a plausible next
epoch of the current generation.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass, field

from coplane.estimation.limits import MAX_SPEED_MPS, RECEIVER_RADIUS_M
from coplane.geo import ecef_to_geodetic
from coplane.gtime import GpsTime
from coplane.messages import SolutionMessage, VehicleState

# Ellipsoidal height of a road vehicle's solved antenna: the Dead Sea shore (-430 m) to the highest
# roads (about 5,800 m), with margin for geoid undulation and a poor fix.
HEIGHT_BAND_M = (-1_000.0, 10_000.0)
MAX_AHEAD_S = 900.0  # GPS seconds a solution may run ahead of the last accepted (recording gaps)
MAX_PACE = 100.0  # epoch seconds per wall second a replay may advance (realtime `speed` at most)
JUMP_MARGIN_M = 500.0  # beyond max speed: an estimator re-initialised from a poor fix
RESTART_QUIET_S = 3.0  # wall seconds of silence after which a new generation counts without `server_gone`
RESYNC_S = 10.0  # wall seconds of only older epochs of this generation before the held head is dropped
MAX_VEHICLES = 4096  # vehicles whose last position is kept (a message holds at most this many)


def on_earth(position_ecef_m: Iterable[float]) -> bool:
    """Whether a solved position is near the Earth's surface (within `HEIGHT_BAND_M`)."""
    x, y, z = (float(v) for v in position_ecef_m)
    r = math.sqrt(x * x + y * y + z * z)
    if not RECEIVER_RADIUS_M[0] <= r <= RECEIVER_RADIUS_M[1]:
        return False  # also keeps the geodetic conversion away from the centre
    h = float(ecef_to_geodetic((x, y, z))[2])
    return HEIGHT_BAND_M[0] <= h <= HEIGHT_BAND_M[1]


@dataclass(frozen=True)
class Verdict:
    """The gate's answer: `solution` is what to use (unknown or jumping vehicles removed), None when
    the message was rejected for `reason`; `reset`: a new server run, forget the old one's state."""

    solution: SolutionMessage | None
    reason: str | None = None
    reset: bool = False
    dropped: tuple[tuple[str, str], ...] = ()  # (vehicle, reason) removed from an accepted message

    @property
    def accepted(self) -> bool:
        return self.solution is not None


@dataclass
class _Run:
    """What was accepted from the current server generation."""

    generation: str | None
    epoch: GpsTime
    accepted_at: float  # wall time of the last accepted message
    seen_at: float  # wall time of the last message of this generation (repeats too)
    positions: dict[str, tuple[GpsTime, tuple[float, float, float]]] = field(default_factory=dict)
    gone: bool = False  # its server withdrew its liveliness token: the next generation may come at once

    def over(self, now: float, quiet_s: float) -> bool:
        """Whether another generation may take over: the server is gone, or silent for `quiet_s`."""
        return self.gone or now - self.seen_at >= quiet_s


class SolutionGate:
    """Accepts or rejects decoded solutions for one fleet; every reason is counted in `counts`.

    Pure: no clock of its own (callers pass `now`, wall seconds), no I/O, no logging (the owner
    decides how to report, rate-limited).
    """

    def __init__(
        self,
        fleet: str,
        *,
        method: str | None = None,
        vehicles: Iterable[str] | None = None,
        max_ahead_s: float = MAX_AHEAD_S,
        max_pace: float = MAX_PACE,
        max_speed_mps: float = MAX_SPEED_MPS,
        jump_margin_m: float = JUMP_MARGIN_M,
        restart_quiet_s: float = RESTART_QUIET_S,
        max_vehicles: int = MAX_VEHICLES,
        resync_s: float = RESYNC_S,
    ) -> None:
        self.fleet = fleet
        self.method = method
        self.vehicles = frozenset(vehicles) if vehicles is not None else None
        self.max_ahead_s = max_ahead_s
        self.max_pace = max_pace
        self.max_speed_mps = max_speed_mps
        self.jump_margin_m = jump_margin_m
        self.restart_quiet_s = restart_quiet_s
        self.max_vehicles = max_vehicles
        self.resync_s = resync_s
        self.counts: Counter[str] = Counter()
        self.accepted = 0
        self.resets = 0
        self.run: _Run | None = None
        self.held: SolutionMessage | None = None  # the latest message of a not yet adopted generation
        self.held_at = 0.0  # when it came
        self.last_reason: str | None = None  # why the latest message was rejected (None: accepted)

    @property
    def generation(self) -> str | None:
        return self.run.generation if self.run is not None else None

    def _reject(self, reason: str) -> Verdict:
        self.counts[reason] += 1
        self.last_reason = reason
        return Verdict(None, reason)

    def check(self, sol: SolutionMessage, now: float, expect: GpsTime | None = None) -> Verdict:
        """Accept (possibly without some vehicles) or reject one solution received at `now`.
        `expect`: the consumer's own current epoch (a vehicle agent's): look-ahead is then bounded
        from it, not from the last accepted epoch, so a recording gap never rejects the awaited one."""
        if sol.fleet != self.fleet:
            return self._reject("wrong-fleet")
        if self.method is not None and sol.method != self.method:
            return self._reject("wrong-method")
        if not all(on_earth(v.position_ecef_m) for v in sol.vehicles):
            return self._reject("off-earth")
        t = GpsTime(sol.epoch.week, sol.epoch.tow)
        run = self.run
        if run is not None and sol.generation != run.generation:
            if not run.over(now, self.restart_quiet_s):
                self.held, self.held_at = sol, now
                return self._reject("new-generation")
            run = None  # the current server has gone: this is its successor
        if expect is not None and t.seconds - expect.seconds > self.max_ahead_s:
            return self._reject("too-far-ahead")  # the consumer knows where the fleet is
        if run is None:
            return self._accept(sol, t, now, reset=self.run is not None)
        run.seen_at = now
        run.gone = False  # its server is back with the same run (a router restart, a resume)
        if t == run.epoch:
            return self._reject("repeat")
        if t < run.epoch:
            if now - run.accepted_at > self.resync_s:
                return self._accept(sol, t, now, reset=True)  # the head we hold was never continued
            return self._reject("stale")
        allowed = self.max_ahead_s + self.max_pace * max(0.0, now - run.accepted_at)
        if expect is None and t.seconds - run.epoch.seconds > allowed:
            return self._reject("too-far-ahead")
        return self._accept(sol, t, now, reset=False)

    def server_gone(self) -> None:
        """The current run's server withdrew its liveliness token: its run is over, and the next
        generation (a restarted server's) is adopted from its first message, not after the quiet
        time. A later message of the same generation continues the run and undoes this (a crashed
        server that resumed from its log, a router restart that re-announced the tokens)."""
        if self.run is not None:
            self.run.gone = True

    def release(self, now: float) -> Verdict | None:
        """The held message of a new generation, accepted once the current run is over (its
        server gone, or silent for `restart_quiet_s`); None while it is not, or nothing is held."""
        sol, run = self.held, self.run
        if sol is not None and run is not None and self.held_at < run.seen_at:
            # the current run went on after it came: a forgery, not its successor (a successor's
            # first solution comes after the old server's last; its next ones are taken anyway)
            self.held = None
            return None
        if sol is None or (run is not None and not run.over(now, self.restart_quiet_s)):
            return None
        self.held = None
        return self.check(sol, now)

    def _accept(self, sol: SolutionMessage, t: GpsTime, now: float, *, reset: bool) -> Verdict:
        """Take `sol` without the vehicles that fail their own checks; if none is left of a
        non-empty message, reject it without moving the epoch (so the genuine one still counts)."""
        fresh = reset or self.run is None
        positions = {} if fresh or self.run is None else self.run.positions
        keep: list[VehicleState] = []
        dropped: list[tuple[str, str]] = []
        for vs in sol.vehicles:
            reason = self._vehicle_reason(positions, len(keep), vs, t)
            if reason is None:
                keep.append(vs)
            else:
                self.counts[reason] += 1
                dropped.append((vs.vehicle_id, reason))
        if sol.vehicles and not keep:
            return self._reject("no-trusted-vehicle")
        if not fresh and positions and not any(vs.vehicle_id in positions for vs in keep):
            # the run follows some vehicles and this message continues none of them (it is empty,
            # or carries only vehicles never seen): taking it would make it the newest epoch and
            # the genuine solution of that epoch a "repeat" (a lockstep agent would stall on it)
            return self._reject("empty" if not sol.vehicles else "no-continuing-vehicle")
        if fresh:
            self.run = _Run(sol.generation, t, now, now)
            self.held = None
            self.resets += reset
        run = self.run
        assert run is not None
        run.epoch, run.accepted_at, run.seen_at = t, now, now
        for vs in keep:
            run.positions[vs.vehicle_id] = (t, vs.position_ecef_m)
        self.accepted += 1
        self.last_reason = None
        out = sol if not dropped else sol.model_copy(update={"vehicles": keep})
        return Verdict(out, reset=reset, dropped=tuple(dropped))

    def _vehicle_reason(
        self,
        positions: dict[str, tuple[GpsTime, tuple[float, float, float]]],
        adding: int,
        vs: VehicleState,
        t: GpsTime,
    ) -> str | None:
        """Why one vehicle of a message is dropped (None: it is kept); `adding`: vehicles of this
        message already kept (they may be new ones, counted against the cap)."""
        if self.vehicles is not None and vs.vehicle_id not in self.vehicles:
            return "vehicle-unknown"
        last = positions.get(vs.vehicle_id)
        if last is None:
            if len(positions) + adding >= self.max_vehicles:
                return "too-many-vehicles"  # with no known set, invented ids must not grow memory
            return None
        t0, p0 = last
        if (
            math.dist(p0, vs.position_ecef_m)
            > self.max_speed_mps * abs(t.seconds - t0.seconds) + self.jump_margin_m
        ):
            return "vehicle-jump"
        return None
