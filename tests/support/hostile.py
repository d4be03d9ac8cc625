"""Valid-but-hostile input for a live fleet (issue 13): Hypothesis strategies and an attacker.

Threat model (docs/reliability/hostile-input.md): the attacker holds ONE enrolled vehicle's
certificate (a compromised vehicle, the recording's last one, whose genuine agent is not run). On
the secure bus it can only put on its own node key, so everything it sends reaches the fusion
server as that vehicle: genuine messages of the compromised vehicle, or other vehicles' genuine
messages re-labelled, then mutated. Every mutation is one a correct server must keep out of the
estimator, so the genuine vehicles' positions must equal a run without the attacker:

    future         epoch minutes .. weeks ahead of the fleet (on the grid)
    past           epoch already solved, or seconds .. weeks before the fleet's first epoch
    off-grid       epoch near the fleet's current one, off the interval grid
    replayed       a genuine message of the compromised vehicle, verbatim (old seq, old epoch)
    duplicate      the previous hostile payload again, byte for byte
    conflicting    the previous hostile message with another fix (same epoch and seq)
    absurd-plane   a plane that contradicts the message (d_antenna 1e3 .. 1e4 m off, or literally
                   1e3 .. 1e4 as in issue 13; sigma 0.01 .. 0.05; normal tilted 0 .. 89 degrees), on
                   an epoch just after the genuine vehicles' last one: the server admits such a
                   message without its plane, and there the compromised vehicle is solved alone, so
                   its solution shows whether the plane was used and no genuine vehicle is touched
    displaced-fix  the SPP fix moved 1 .. 2000 km along the ground, plane moved with it, on one of
                   the next three epochs
    oversized      a hostile message padded with JSON whitespace to just under 1 MiB (decodes),
                   above 1 MiB (decode's limit) or above 2 MiB (Zenoh's transport limit)

Forged solutions (the attacker's `SolutionMessage`s on the solution key; on the secure bus the
router drops them, on an insecure bus they reach every consumer):

    other-fleet, off-earth (a vehicle at the Earth's centre or 16,000 km out), stale-epoch and
    future-epoch (1 .. 520 weeks), jump (a genuine solution with every vehicle moved 5 .. 50 km),
    unknown-generation (a genuine solution re-stamped with another server run), empty (a genuine
    epoch with no vehicles), flood (hundreds of made-up vehicle ids). All but unknown-generation
    carry the live server's generation. Not among them: a plausible next epoch of the live
    generation (genuine-looking positions), which no consumer can tell from the server's own on an
    insecure bus (coplane.bus.trust, residual risk); `plausible-next` builds one for the bench.

The strategies draw a *spec* (kind and parameters); `build_node` / `build_solution` turn it into
bytes at send time, relative to the fleet's newest solved epoch, so "future" and "next epoch" mean
what they say in a live run. `draw_all` collects a fixed number of specs deterministically
(`derandomize=True`): CI and the bench send the same attack every time.
"""

from __future__ import annotations

import contextlib
import math
import tempfile
import threading
import time
from collections import Counter, defaultdict
from collections.abc import Callable, Collection, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import zenoh
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

from coplane.bus import (
    MONITOR,
    BadMessage,
    BusEvent,
    BusNode,
    BusSecurity,
    KeySpace,
    Payload,
    Presence,
    Subscription,
    decode,
    encode,
    session_config,
)
from coplane.bus.codec import MAX_PAYLOAD_BYTES
from coplane.evaluate.runner import run_method
from coplane.fleet import (
    Collector,
    FleetProcesses,
    fleet_of,
)
from coplane.gtime import GpsTime
from coplane.messages import DiagnosticsMessage, NodeMessage, PlaneReport, SolutionMessage, SppReport
from coplane.recording.reader import open_recording
from coplane.steps import epoch_time, gps_time
from support.e2e_fleet import live_fleet

NODE_KINDS = (
    "future",
    "past",
    "off-grid",
    "replayed",
    "duplicate",
    "conflicting",
    "absurd-plane",
    "displaced-fix",
    "oversized",
)
SOLUTION_KINDS = (
    "other-fleet",
    "off-earth",
    "stale-epoch",
    "future-epoch",
    "jump",
    "unknown-generation",
    "empty",
    "flood",
)
WEEK_S = 604800.0
FORGED_SEQ = 1_000_000  # forged solutions' seq starts here (how the harness tells them apart)
TRANSPORT_LIMIT = 2 * MAX_PAYLOAD_BYTES  # Zenoh drops larger messages in transit (docs/bus.md)


# -- genuine material ------------------------------------------------------------------------------


@dataclass
class Genuine:
    """What the in-process replay of the whole recording produced: every vehicle's node message and
    the solution of every epoch (the attacker's raw material), in epoch order."""

    messages: dict[str, list[NodeMessage]]
    solutions: list[SolutionMessage]
    interval_s: float

    @property
    def epochs(self) -> list[GpsTime]:
        return [gps_time(s.epoch) for s in self.solutions]


def genuine_material(recording: Path, method: str) -> Genuine:
    msgs: dict[str, list[NodeMessage]] = defaultdict(list)
    sols: list[SolutionMessage] = []

    def keep(sol: SolutionMessage, m: dict[str, NodeMessage]) -> None:
        sols.append(sol)
        for vid, msg in m.items():
            msgs[vid].append(msg)

    rec = open_recording(recording)
    run_method(rec, method, on_solution=keep, jobs=1)
    return Genuine(dict(msgs), sols, rec.manifest.interval_s)


def clean_reference(recording: Path, method: str, vehicles: Sequence[str]) -> dict[str, dict[GpsTime, Any]]:
    """The genuine vehicles' positions without the attacker: the in-process lockstep replay of
    `vehicles` (bit for bit what a clean lockstep run over the bus gives, tests/fleet/test_fleet_e2e.py)."""
    run = run_method(open_recording(recording), method, vehicles=list(vehicles), jobs=1)
    return {v: dict(p) for v, p in run.positions.items()}


# -- specs (what Hypothesis draws) -----------------------------------------------------------------


@dataclass(frozen=True)
class NodeAttack:
    kind: str
    source: int = 0  # 0: the compromised vehicle's own messages, k: the k-th other vehicle's, re-labelled
    pick: int = 0  # which base message (modulo the number available)
    offset_s: float = 0.0  # future / past / off-grid: how far from the fleet's epoch
    ahead: int = 1  # absurd-plane / displaced-fix: epochs after the newest solved one
    shift_m: float = 0.0  # displaced-fix / conflicting: how far the fix moves
    bearing: float = 0.0  # direction of the move, radians
    plane: tuple[float, float, float] = (0.0, 0.01, 0.0)  # absurd: (offset m or literal d, sigma, tilt deg)
    literal_d: bool = False  # absurd-plane: d_antenna_m itself is the drawn value (the 1e4)
    size: int = 0  # oversized: payload bytes
    inner: str = "future"  # oversized: the hostile message that is padded


@dataclass(frozen=True)
class SolutionAttack:
    kind: str
    pick: int = 0
    vehicle: int = 0
    offset_s: float = 0.0
    shift_m: float = 0.0
    bearing: float = 0.0
    up: bool = False
    count: int = 0
    generation: str = ""


_grid_ahead = st.integers(60, 4 * 7 * 86400)  # seconds: a minute .. four weeks


@st.composite
def node_attacks(draw: st.DrawFn, kinds: Sequence[str] = NODE_KINDS) -> NodeAttack:
    """One hostile node-message spec (see the module docstring)."""
    kind = draw(st.sampled_from(list(kinds)))
    source = draw(st.integers(0, 3))
    pick = draw(st.integers(0, 10_000))
    if kind == "future":
        return NodeAttack(kind, source, pick, offset_s=float(draw(_grid_ahead)))
    if kind == "past":
        # 0 .. 10 epochs before the newest solved one, or a minute .. weeks before the fleet's start
        back = draw(st.one_of(st.integers(0, 10).map(lambda k: -float(k)), _grid_ahead.map(float)))
        return NodeAttack(kind, source, pick, offset_s=back)
    if kind == "off-grid":
        k = draw(st.integers(-3, 5))
        frac = draw(st.floats(0.001, 0.999, allow_nan=False))
        return NodeAttack(kind, source, pick, offset_s=k + frac)
    if kind in ("absurd-plane", "displaced-fix", "conflicting"):
        plane = (
            draw(st.floats(1e3, 1e4)),
            draw(st.sampled_from([0.01, 0.02, 0.05])),
            draw(st.floats(0.0, 89.0)),
        )
        return NodeAttack(
            kind,
            source,
            pick,
            ahead=draw(st.integers(1, 3)),
            shift_m=draw(st.floats(1e3, 2e6)),
            bearing=draw(st.floats(0.0, 2 * math.pi)),
            plane=plane,
            literal_d=draw(st.booleans()),
        )
    if kind == "oversized":
        size = draw(
            st.one_of(
                st.integers(MAX_PAYLOAD_BYTES - 65536, MAX_PAYLOAD_BYTES),  # decodes
                st.integers(MAX_PAYLOAD_BYTES + 1, MAX_PAYLOAD_BYTES + 131072),  # decode's limit
                st.integers(TRANSPORT_LIMIT + 1, TRANSPORT_LIMIT + 262144),  # Zenoh's limit
            )
        )
        inner = draw(st.sampled_from(["future", "past", "off-grid", "displaced-fix"]))
        return NodeAttack(
            kind,
            source,
            pick,
            offset_s=float(draw(_grid_ahead)),
            size=size,
            inner=inner,
            shift_m=5e4,
            ahead=1,
        )
    return NodeAttack(kind, source, pick)  # replayed, duplicate


@st.composite
def solution_attacks(draw: st.DrawFn, kinds: Sequence[str] = SOLUTION_KINDS) -> SolutionAttack:
    """One forged-solution spec (see the module docstring)."""
    kind = draw(st.sampled_from(list(kinds)))
    return SolutionAttack(
        kind,
        pick=draw(st.integers(0, 10_000)),
        vehicle=draw(st.integers(0, 63)),
        offset_s=float(draw(st.integers(1, 520)) * WEEK_S / 52)
        if kind in ("stale-epoch", "future-epoch")
        else 0.0,
        shift_m=draw(st.floats(5e3, 5e4)),  # the forgery moved a vehicle by 5 km
        bearing=draw(st.floats(0.0, 2 * math.pi)),
        up=draw(st.booleans()),
        count=draw(st.integers(100, 1000)) if kind == "flood" else 0,
        generation=draw(st.text("0123456789abcdef", min_size=8, max_size=32)),
    )


def balanced(
    strategy: Callable[[Sequence[str]], st.SearchStrategy[Any]], kinds: Sequence[str], n: int
) -> list[Any]:
    """`n` specs, an equal share of every kind, interleaved (kind 1, kind 2, ..., kind 1, ...)."""
    per = [draw_all(strategy([k]), -(-n // len(kinds))) for k in kinds]
    return [per[i % len(kinds)][i // len(kinds)] for i in range(n)]


def draw_all(strategy: st.SearchStrategy[Any], n: int) -> list[Any]:
    """`n` examples of `strategy`, the same ones on every run (Hypothesis, derandomized; a test body
    that only collects, so Hypothesis' own limits on one example's size do not apply)."""
    out: list[Any] = []

    @settings(
        max_examples=n,
        derandomize=True,
        database=None,
        deadline=None,
        phases=[Phase.generate],
        suppress_health_check=list(HealthCheck),
    )
    @given(strategy)
    def collect(x: Any) -> None:
        out.append(x)

    collect()
    while len(out) < n:  # Hypothesis may stop early (it skips repeats): cycle deterministically
        out.append(out[len(out) % max(1, len(out))])
    return out[:n]


# -- building payloads at send time ----------------------------------------------------------------


def _tangent(p: Any, bearing: float) -> np.ndarray:
    """A unit vector along the ground at ECEF `p`, `bearing` radians from north."""
    r = np.asarray(p, dtype=float)
    up = r / np.linalg.norm(r)
    east = np.cross([0.0, 0.0, 1.0], up)
    east /= np.linalg.norm(east)
    north = np.cross(up, east)
    return math.cos(bearing) * north + math.sin(bearing) * east


def _tilted(n: Sequence[float], deg: float, bearing: float) -> tuple[float, float, float]:
    v = np.asarray(n, dtype=float)
    t = _tangent(v * 6.4e6, bearing)
    a = math.radians(deg)
    out = math.cos(a) * v + math.sin(a) * t
    out /= np.linalg.norm(out)
    return (float(out[0]), float(out[1]), float(out[2]))


def _t3(v: Any) -> tuple[float, float, float]:
    return (float(v[0]), float(v[1]), float(v[2]))


def displaced(msg: NodeMessage, shift_m: float, bearing: float) -> NodeMessage:
    """The SPP fix moved `shift_m` along the ground; the plane (if any) moved with it, so the
    message looks consistent except against its own pseudoranges."""
    if msg.spp.position_ecef_m is None:
        return msg
    p = np.asarray(msg.spp.position_ecef_m)
    s = shift_m * _tangent(p, bearing)
    spp = msg.spp.model_copy(update={"position_ecef_m": _t3(p + s)})
    upd: dict[str, Any] = {"spp": SppReport.model_validate(spp.model_dump())}
    pl = msg.plane
    if pl is not None and pl.normal is not None and pl.d_antenna_m is not None:
        dn = float(np.dot(pl.normal, s))
        fields: dict[str, Any] = {"d_antenna_m": pl.d_antenna_m - dn}
        if pl.d_road_m is not None:
            fields["d_road_m"] = pl.d_road_m - dn
        if pl.centroid_ecef_m is not None:
            fields["centroid_ecef_m"] = _t3(np.asarray(pl.centroid_ecef_m) + s)
        upd["plane"] = PlaneReport.model_validate(pl.model_copy(update=fields).model_dump())
    return msg.model_copy(update=upd)


def absurd_plane(msg: NodeMessage, a: NodeAttack) -> NodeMessage:
    offset, sigma, tilt = a.plane
    p = msg.spp.position_ecef_m or (6.4e6, 0.0, 0.0)
    up = np.asarray(p) / np.linalg.norm(p)
    base_n = msg.plane.normal if msg.plane is not None and msg.plane.normal is not None else _t3(up)
    n = _tilted(base_n, tilt, a.bearing)
    d = offset if a.literal_d else -float(np.dot(n, p)) + offset
    plane = PlaneReport(
        status="available",
        normal=n,
        d_antenna_m=d,
        d_road_m=d + msg.antenna_height_m,
        sigma_m=sigma,
        offset_sigma_m=sigma,
        tilt_sigma_rad=0.001,
        residual_max_m=0.01,
        residual_rms_m=0.005,
        n_points_initial=400,
        n_points_used=400,
        centroid_ecef_m=_t3(p),
    )
    return msg.model_copy(update={"plane": plane})


@dataclass
class AttackContext:
    """The fleet as the attacker sees it when it sends, and what it sent so far."""

    genuine: Genuine
    attacker: str  # the compromised vehicle id
    newest: GpsTime  # the newest epoch the fleet has solved
    first: GpsTime  # the fleet's first epoch
    end: GpsTime  # the genuine vehicles' last epoch
    seq: int = 1_000_000  # the attacker's own sequence numbers (fresh: not replays)
    last: NodeMessage | None = None
    last_payload: bytes | None = None

    def base(self, a: NodeAttack, near: GpsTime | None = None, fix: bool = False) -> NodeMessage:
        """A genuine message to mutate: the attacker's own, or another vehicle's re-labelled; the
        one nearest `near` if given (its satellites then match that epoch), else any."""
        vids = sorted(self.genuine.messages)
        others = [v for v in vids if v != self.attacker]
        src = self.attacker if a.source == 0 or not others else others[(a.source - 1) % len(others)]
        pool = self.genuine.messages[src]
        if fix:  # only messages with an SPP fix (a message without one has nothing to displace)
            pool = [m for m in pool if m.spp.position_ecef_m is not None] or pool
        if near is not None:
            m = min(pool, key=lambda m: abs(gps_time(m.epoch) - near))
        else:
            m = pool[a.pick % len(pool)]
        if src != self.attacker:
            m = m.model_copy(
                update={"vehicle_id": self.attacker, "ranges": [r for r in m.ranges if r.to != self.attacker]}
            )
        return m

    def at(self, m: NodeMessage, t: GpsTime) -> NodeMessage:
        """`m` re-stamped at `t` (its receiver tag moved by the same amount), with a fresh seq."""
        dt = t - gps_time(m.epoch)
        self.seq += 1
        rx = epoch_time(gps_time(m.rx_time) + dt)
        return m.model_copy(update={"epoch": epoch_time(t), "rx_time": rx, "seq": self.seq})


def _pad(payload: bytes, size: int) -> bytes:
    """JSON whitespace before the closing brace: still the same valid message, `size` bytes."""
    extra = max(0, size - len(payload))
    return payload[:-1] + b" " * extra + payload[-1:]


def build_node(a: NodeAttack, ctx: AttackContext) -> bytes:
    """The payload of one hostile node message, relative to the fleet's newest solved epoch."""
    dt = ctx.genuine.interval_s
    kind = a.inner if a.kind == "oversized" else a.kind
    msg: NodeMessage
    if kind == "duplicate" and ctx.last_payload is not None:
        return ctx.last_payload
    if kind == "conflicting" and ctx.last is not None:
        msg = displaced(ctx.last, a.shift_m / 100.0, a.bearing)  # same epoch and seq, another fix
    elif kind in ("duplicate", "conflicting", "replayed"):
        # a genuine message of the compromised vehicle from an epoch the fleet has already solved
        own = [m for m in ctx.genuine.messages[ctx.attacker] if gps_time(m.epoch) < ctx.newest]
        msg = (own or ctx.genuine.messages[ctx.attacker])[a.pick % max(1, len(own))]
        payload = encode(msg)
        ctx.last, ctx.last_payload = msg, payload
        return payload
    elif kind == "future":
        t = ctx.newest + math.ceil(a.offset_s / dt) * dt
        msg = ctx.at(ctx.base(a), t)
    elif kind == "past":
        t = (
            ctx.newest + a.offset_s * dt
            if a.offset_s <= 0
            else ctx.first + (-math.ceil(a.offset_s / dt) * dt)
        )
        msg = ctx.at(ctx.base(a, near=t), t)
    elif kind == "off-grid":
        t = ctx.newest + a.offset_s * dt
        msg = ctx.at(ctx.base(a, near=t), t)
    elif kind == "displaced-fix":
        t = ctx.newest + a.ahead * dt
        msg = displaced(ctx.at(ctx.base(a, near=t, fix=True), t), a.shift_m, a.bearing)
    elif kind == "absurd-plane":
        # just after the genuine vehicles' last epoch: an otherwise plausible message is admitted
        # there without its plane, and solved with the compromised vehicle alone, so its solution
        # shows whether the plane was used (and no genuine vehicle is touched)
        t = ctx.end + a.ahead * dt
        msg = absurd_plane(ctx.at(ctx.base(a, near=ctx.end, fix=True), t), a)
    else:
        raise ValueError(f"unknown node attack {a.kind!r}")
    payload = encode(msg)
    ctx.last, ctx.last_payload = msg, payload
    if a.kind == "oversized":
        payload = _pad(payload, a.size)
    return payload


def build_solution(
    a: SolutionAttack,
    genuine: Genuine,
    newest: GpsTime,
    generation: str | None,
    vehicles: Collection[str] | None = None,
) -> bytes:
    """One forged solution, from the genuine solution nearest the fleet's newest epoch (stamped with
    the live server's `generation` unless the forgery is about the generation); `vehicles`: keep
    only these of the genuine solution's vehicles (None: all, the compromised one included)."""
    sols = genuine.solutions
    near = min(sols, key=lambda s: abs(gps_time(s.epoch) - newest))
    i = sols.index(near)
    sol = sols[min(len(sols) - 1, i + a.pick % 3)]  # this epoch or one of the next two
    upd: dict[str, Any] = {"generation": generation, "seq": sol.seq + FORGED_SEQ}
    t = gps_time(sol.epoch)
    vs = [v for v in sol.vehicles if vehicles is None or v.vehicle_id in vehicles]
    upd["vehicles"] = vs  # the kinds below change them in place, or replace them
    k = a.vehicle % len(vs)
    if a.kind == "other-fleet":
        upd["fleet"] = sol.fleet[:-1] + ("x" if sol.fleet[-1] != "x" else "y")  # a valid id, not ours
    elif a.kind == "off-earth":
        p = vs[k].position_ecef_m
        pos = (0.0, 0.0, 0.0) if a.up else _t3(np.asarray(p) / np.linalg.norm(p) * 1.6e7)
        vs[k] = vs[k].model_copy(update={"position_ecef_m": pos})
        upd["vehicles"] = vs
    elif a.kind == "stale-epoch":
        upd["epoch"] = epoch_time(t + (-a.offset_s))
    elif a.kind == "future-epoch":
        upd["epoch"] = epoch_time(t + a.offset_s)
    elif a.kind == "jump":  # every vehicle jumps (one jumping beside plausible ones: see the docstring)
        for j, v in enumerate(vs):
            p = np.asarray(v.position_ecef_m)
            step = a.shift_m * _tangent(p, a.bearing + j)
            vs[j] = v.model_copy(update={"position_ecef_m": _t3(p + step)})
        upd["vehicles"] = vs
    elif a.kind == "unknown-generation":
        g = a.generation if a.generation != generation else a.generation[::-1] + "0"
        upd["generation"] = g if len(g) >= 8 else (g + "00000000")[:8]
    elif a.kind == "plausible-next":  # one vehicle 5 .. 50 km off beside plausible ones
        p = np.asarray(vs[k].position_ecef_m)
        vs[k] = vs[k].model_copy(update={"position_ecef_m": _t3(p + a.shift_m * _tangent(p, a.bearing))})
        upd["vehicles"] = vs
    elif a.kind == "empty":
        upd["vehicles"] = []
    elif a.kind == "flood":
        proto = vs[k]
        upd["vehicles"] = [proto.model_copy(update={"vehicle_id": f"x{j}"}) for j in range(a.count)]
    else:
        raise ValueError(f"unknown solution attack {a.kind!r}")
    return encode(sol.model_copy(update=upd))


# -- the fleet and the attacker --------------------------------------------------------------------


@dataclass
class HostileFleet:
    procs: FleetProcesses
    collector: Collector
    connect: str
    fleet: str
    vehicles: list[str]  # the genuine ones (agents running)
    attacker: str
    security: BusSecurity  # the fleet's (insecure or the certificates folder)


@contextmanager
def hostile_fleet(
    recording: Path,
    method: str,
    attacker: str,
    pace: str = "lockstep",
    speed: float = 1.0,
    secure: bool = True,
    log_dir: Path | None = None,
    start_delay_s: float = 8.0,
    extra_fusion_args: Sequence[str] = (),
) -> Iterator[HostileFleet]:
    """`live_fleet` without `attacker`'s agent (the attacker holds its certificate)."""
    _, vehicles = fleet_of(recording)
    genuine = [v for v in vehicles if v != attacker]
    with live_fleet(
        recording, method, pace, speed, log_dir, extra_fusion_args, start_delay_s, secure, agents=genuine
    ) as lf:
        yield HostileFleet(lf.procs, lf.collector, lf.connect, lf.fleet, genuine, attacker, lf.security)


class Attacker:
    """A session as `identity` (a vehicle's certificate on the secure bus; anyone on an insecure
    one) that puts raw payloads on node and solution keys, reliably (BLOCK: none lost in transit on
    the attacker's side)."""

    def __init__(self, hf: HostileFleet, identity: str) -> None:
        sec = hf.security.as_identity(identity) if hf.security.secure else hf.security
        self.keys = KeySpace(hf.fleet)
        self.session = zenoh.open(session_config("client", [hf.connect], security=sec))
        block, reliable = zenoh.CongestionControl.BLOCK, zenoh.Reliability.RELIABLE
        self.node_pub = self.session.declare_publisher(
            self.keys.node(hf.attacker), congestion_control=block, reliability=reliable
        )
        self.sol_pub = self.session.declare_publisher(
            self.keys.solution, congestion_control=block, reliability=reliable
        )
        self.token: Any = None

    def put_node(self, payload: bytes) -> None:
        self.node_pub.put(payload)

    def put_solution(self, payload: bytes) -> None:
        self.sol_pub.put(payload)

    def declare_token(self, key: str) -> None:
        self.token = self.session.liveliness().declare_token(key)

    def close(self) -> None:
        with contextlib.suppress(Exception):
            if self.token is not None:
                self.token.undeclare()
        self.session.close()


@dataclass
class AttackLog:
    """What was sent, by kind, and what the bus did with it."""

    node_sent: Counter[str] = field(default_factory=Counter)
    node_bytes: int = 0
    node_over_transport: int = 0  # payloads above Zenoh's limit: dropped in transit
    solutions_sent: Counter[str] = field(default_factory=Counter)
    send_errors: int = 0


class Watch:
    """Every diagnostics message (the collector keeps only the newest) and every payload on the
    solution key, as a read-only listener (the monitor identity on the secure bus)."""

    def __init__(self, hf: HostileFleet) -> None:
        self.keys = KeySpace(hf.fleet)
        self.lock = threading.Lock()
        self.diags: list[DiagnosticsMessage] = []
        self.solution_payloads = 0
        self.generation: str | None = None  # the live server's (from its first solution)
        self.fusion_alive = False
        self.forged = 0  # forged solutions (seq marked by build_solution) that reached this listener
        self.node = BusNode(
            session_config("client", [hf.connect]),
            subscribe=[
                Subscription(self.keys.solution),
                Subscription(self.keys.diagnostics),
                Subscription(self.keys.all_alive("fusion"), liveliness=True),
            ],
            sink=self._on_event,
        ).open()

    def _on_event(self, ev: BusEvent) -> None:
        if isinstance(ev, Presence):
            self.fusion_alive = self.fusion_alive or ev.alive
            return
        if not isinstance(ev, Payload):
            return
        if ev.key == self.keys.solution:
            try:
                sol: SolutionMessage | None = decode(SolutionMessage, ev.data)
            except BadMessage:
                sol = None
            with self.lock:
                self.solution_payloads += 1
                if sol is None or sol.seq >= FORGED_SEQ:
                    self.forged += 1
                elif self.generation is None:
                    self.generation = sol.generation
            return
        with contextlib.suppress(BadMessage):
            d = decode(DiagnosticsMessage, ev.data)
            with self.lock:
                self.diags.append(d)

    @property
    def last(self) -> DiagnosticsMessage | None:
        with self.lock:
            return self.diags[-1] if self.diags else None

    def pending_max(self) -> tuple[int, int]:
        """(max pending_epochs, min pending_limit) over every diagnostics message."""
        with self.lock:
            return (
                max((d.pending_epochs for d in self.diags), default=0),
                min((d.pending_limit for d in self.diags), default=0),
            )

    def close(self) -> None:
        self.node.close()


def newest_solved(col: Collector) -> GpsTime | None:
    with col.lock:
        ts = [t for pos in col.run.positions.values() for t in pos]
    return max(ts) if ts else None


def send_node(att: Attacker, a: NodeAttack, ctx: AttackContext, log: AttackLog) -> None:
    payload = build_node(a, ctx)
    try:
        att.put_node(payload)
    except Exception:
        log.send_errors += 1
        return
    log.node_sent[a.kind] += 1
    log.node_bytes += len(payload)
    log.node_over_transport += len(payload) > TRANSPORT_LIMIT


def max_position_diff(
    ref: dict[str, dict[GpsTime, Any]], got: dict[str, dict[GpsTime, Any]]
) -> tuple[float, int, list[str]]:
    """(max |got - ref| over the reference's epochs, positions compared, problems: missing or
    extra epochs per vehicle)."""
    worst, n, problems = 0.0, 0, []
    for vid, pos in ref.items():
        g = got.get(vid, {})
        if set(pos) != set(g):
            problems.append(f"{vid}: {len(set(pos) - set(g))} epochs missing, {len(set(g) - set(pos))} extra")
        for t, p in pos.items():
            if t in g:
                worst = max(worst, float(np.linalg.norm(np.asarray(g[t]) - np.asarray(p))))
                n += 1
    return worst, n, problems


# -- one attacked run, end to end ------------------------------------------------------------------


@dataclass
class AttackRun:
    """What one attacked (or clean) fleet run measured."""

    label: str
    pace: str
    secure: bool
    log: AttackLog
    positions: dict[str, dict[GpsTime, Any]]
    epochs_published: int  # solutions the collector took
    solution_payloads: int  # every payload on the solution key the monitor saw (forged included)
    forged_seen: int  # forged solutions among them
    diag: DiagnosticsMessage | None
    pending_max: int
    pending_limit: int
    n_diagnostics: int
    crashed: list[str]  # processes that died before the end (name: exit code)
    exit_codes: dict[str, int | None]
    collector_bad: int
    wall_s: float
    send_s: float
    attack_overlap: float  # share of the attack sent before the genuine run (agents, solves) ended
    per_kind: dict[str, dict[str, int]]  # by_kind runs: the server's counters moved by each kind
    attacker_positions: dict[GpsTime, Any]  # the compromised vehicle in published solutions
    attacker_plane_used: dict[GpsTime, bool]
    untrusted: Counter[str]  # the collector's gate: forged solutions (or vehicles) it dropped, by reason
    timed_out: list[str]  # what did not happen in time (a stalled fleet)


def run_attack(
    recording: Path,
    method: str,
    attacker: str,
    genuine: Genuine,
    node_specs: Sequence[NodeAttack] = (),
    solution_specs: Sequence[SolutionAttack] = (),
    *,
    pace: str = "lockstep",
    speed: float = 1.0,
    secure: bool = True,
    log_dir: Path | None = None,
    start_delay_s: float = 8.0,
    per_round: int = 25,
    round_s: float = 0.0,
    token: bool = False,
    by_kind: bool = False,
    early_specs: Sequence[NodeAttack] = (),
    forge_vehicles: Collection[str] | None = None,
    max_ahead_s: float = 25.0,
    label: str = "",
    timeout_s: float = 120.0,
    follow_fleet: bool = False,
) -> AttackRun:
    """Run the fleet without `attacker`'s agent; once it solves, send the node attacks as the
    attacker's vehicle and the forged solutions on the solution key (interleaved, in rounds, each
    round built against the newest solved epoch); then let the genuine agents finish and stop the
    fusion server cleanly (its final diagnostics). `follow_fleet`: round k of n waits until the
    fleet has solved its k/n share of the epochs (or the agents are done), so the attack spreads
    over the genuine run however fast this host solves; otherwise rounds follow `round_s`."""
    from coplane.bus.security import vehicle_identity

    t_start = time.monotonic()
    log = AttackLog()
    per_kind: dict[str, dict[str, int]] = {}
    timed_out: list[str] = []
    with (
        tempfile.TemporaryDirectory(prefix="coplane-hostile-db-") as db,
        hostile_fleet(
            recording,
            method,
            attacker,
            pace,
            speed,
            secure,
            log_dir,
            start_delay_s,
            # its own solution log: never a resume from another run's (same fleet, a reused port);
            # realtime: the server waits for the fleet at least until the agents' shared start, so
            # the attacker's early messages are never solved alone before the genuine ones come
            extra_fusion_args=[
                "--db",
                str(Path(db) / "fusion.sqlite"),
                *(["--startup_wait_s", str(max(10.0, start_delay_s + 5.0))] if pace == "realtime" else []),
            ],
        ) as hf,
        contextlib.closing(Watch(hf)) as watch,
    ):
        col, procs = hf.collector, hf.procs
        att = Attacker(hf, vehicle_identity(attacker) if secure else MONITOR)
        generation: str | None = None
        first = min(genuine.epochs)
        ctx = AttackContext(genuine, attacker, first, first, max(genuine.epochs))
        if early_specs:  # before the fleet: as soon as the fusion server is up, before any agent sends
            _wait(lambda: watch.fusion_alive, timeout_s, "the fusion server's liveliness token")
            time.sleep(0.3)  # its subscriber is declared before its token; the router learns both
            for a in early_specs:
                send_node(att, a, ctx, log)
        _wait(lambda: col.epochs >= 1, timeout_s, "the first solution")
        ctx.newest = newest_solved(col) or first
        if by_kind and early_specs:  # the early ones are not any kind's: account for them first
            _settle(watch, attacker, len(early_specs), 0)
        if token:
            att.declare_token(KeySpace(hf.fleet).alive("agent", attacker))
        groups = _groups(node_specs, solution_specs, by_kind)
        agents = [n for n in procs.procs if n.startswith("agent-")]

        def agents_done() -> bool:
            return all(procs.procs[a].poll() is not None for a in agents)

        sent_live = n_items = k_round = 0
        n_rounds = sum(-(-len(items) // per_round) for _, items in groups)
        paced = genuine.epochs[:-2] or genuine.epochs  # the agents exit once their last node is out

        def genuine_running() -> bool:
            # the agents may exit once their nodes are out while the server still solves them
            return not agents_done() or (newest_solved(col) or first) < ctx.end

        def fleet_reached(k: int) -> Callable[[], bool]:
            target = paced[min(len(paced) - 1, k * len(paced) // max(1, n_rounds))]
            return lambda: not genuine_running() or (newest_solved(col) or first) >= target

        t0 = time.monotonic()
        try:
            for kind, items in groups:
                if by_kind and kind == "absurd-plane":  # once its epochs are within the window
                    near = ctx.end + (-max_ahead_s)

                    def near_end(n: GpsTime = near) -> bool:
                        return (newest_solved(col) or first) >= n

                    _wait(near_end, timeout_s, "the fleet near its last epoch", fail=False)
                before = _snapshot(watch, attacker)
                n_diag, node_before = len(watch.diags), log.node_sent.total() - log.node_over_transport
                for i in range(0, len(items), per_round):
                    if follow_fleet:
                        # a lockstep epoch solves in milliseconds: 10 s bounds a stalled fleet's cost
                        _wait(fleet_reached(k_round), 10.0, "the fleet's progress", fail=False)
                    k_round += 1
                    r0 = time.monotonic()
                    ctx.newest = newest_solved(col) or ctx.newest
                    if generation is None:
                        generation = watch.generation
                    live = genuine_running()
                    for x in items[i : i + per_round]:
                        if isinstance(x, NodeAttack):
                            send_node(att, x, ctx, log)
                        else:
                            try:
                                forged = build_solution(x, genuine, ctx.newest, generation, forge_vehicles)
                                att.put_solution(forged)
                                log.solutions_sent[x.kind] += 1
                            except Exception:
                                log.send_errors += 1
                        sent_live += live
                        n_items += 1
                    time.sleep(max(0.0, round_s - (time.monotonic() - r0)))
                if by_kind:  # account for this kind: diagnostics that include every payload sent
                    arrived = log.node_sent.total() - log.node_over_transport
                    _settle(watch, attacker, arrived - node_before, n_diag)
                    per_kind[kind] = _diff(_snapshot(watch, attacker), before)
            send_s = time.monotonic() - t0
            if not _wait(agents_done, timeout_s, "the genuine agents to finish", fail=False):
                timed_out.append(f"the genuine agents did not finish within {timeout_s:.0f} s")
            time.sleep(1.0 + 1.0 / speed)  # the last epochs' deadline, then the server's queue
        finally:
            att.close()
        alive_before_stop = {n: p.poll() for n, p in procs.procs.items()}
        procs.stop("fusion-server")
        _wait(lambda: procs.procs["fusion-server"].poll() is not None, 15, "the server to stop", fail=False)
        time.sleep(0.3)
        crashed = [
            f"{n}: {c}"
            for n, c in alive_before_stop.items()
            if c not in (None, 0) or (n in ("fusion-server", "zenoh-router") and c is not None)
        ]
        codes = {n: p.poll() for n, p in procs.procs.items()}
        if codes.get("fusion-server") not in (0, None, 143, -15):
            crashed.append(f"fusion-server stop: {codes['fusion-server']}")
        with col.lock:
            positions = {v: dict(p) for v, p in col.run.positions.items()}
            epochs = col.epochs
            bad = col.bad
            attacker_pos = dict(col.run.positions.get(attacker, {}))
            attacker_plane = dict(col.run.plane_used.get(attacker, {}))
            untrusted = Counter(getattr(col, "untrusted", {}))
        pmax, plim = watch.pending_max()
        return AttackRun(
            label or f"{pace}{'' if secure else ' insecure'}",
            pace,
            secure,
            log,
            positions,
            epochs,
            watch.solution_payloads,
            watch.forged,
            watch.last,
            pmax,
            plim,
            len(watch.diags),
            crashed,
            codes,
            bad,
            time.monotonic() - t_start,
            send_s,
            sent_live / max(1, n_items),
            per_kind,
            attacker_pos,
            attacker_plane,
            untrusted,
            timed_out,
        )


def _wait(cond: Callable[[], bool], timeout: float, what: str, fail: bool = True) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if cond():
            return True
        time.sleep(0.05)
    if fail:
        raise AssertionError(f"timed out after {timeout} s waiting for {what}")
    return False


def _groups(
    node_specs: Sequence[NodeAttack], solution_specs: Sequence[SolutionAttack], by_kind: bool
) -> list[tuple[str, list[Any]]]:
    """The send order: node attacks and forged solutions interleaved; `by_kind`: one group per node
    attack kind (each group also carries its share of the forged solutions)."""
    if not by_kind:
        items: list[Any] = []
        for i in range(max(len(node_specs), len(solution_specs))):
            items += [*node_specs[i : i + 1], *solution_specs[i : i + 1]]
        return [("all", items)]
    kinds = list(dict.fromkeys(a.kind for a in node_specs))
    if "absurd-plane" in kinds:  # last: its epochs are just after the genuine end (see build_node)
        kinds = [k for k in kinds if k != "absurd-plane"] + ["absurd-plane"]
    out = []
    for j, k in enumerate(kinds):
        nodes = [a for a in node_specs if a.kind == k]
        sols = list(solution_specs[j :: len(kinds)])
        group: list[Any] = []
        for i in range(max(len(nodes), len(sols))):
            group += [*nodes[i : i + 1], *sols[i : i + 1]]
        out.append((k, group))
    return out


def _snapshot(watch: Watch, vid: str) -> Counter[str]:
    d = watch.last
    out: Counter[str] = Counter()
    if d is None:
        return out
    c = d.vehicles.get(vid)
    if c is not None:
        for f in ("received", "used", "rejected", "late", "duplicate"):
            out[f] = getattr(c, f)
    for r, n in d.rejected_by_reason.items():
        out["reason:" + r] = n
    out["node_payloads"] = d.node_payloads
    return out


def _diff(after: Counter[str], before: Counter[str]) -> dict[str, int]:
    return {k: after[k] - before[k] for k in after if after[k] != before[k]}


def _settle(watch: Watch, vid: str, expected: int, n_diag: int, timeout: float = 6.0) -> None:
    """Wait until a diagnostics message newer than `n_diag` shows the vehicle's `expected` new
    payloads received (or `timeout`)."""
    base = watch.diags[n_diag - 1].vehicles.get(vid) if n_diag else None
    start = base.received if base is not None else 0
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        d = watch.last
        c = d.vehicles.get(vid) if d is not None else None
        if len(watch.diags) > n_diag + 1 and c is not None and c.received - start >= expected:
            return
        time.sleep(0.05)
