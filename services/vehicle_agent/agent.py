"""Vehicle agent: replays one vehicle of a recording through VehicleStep and talks to the bus.

Lockstep: publish epoch t, wait for the fleet solution of t (re-sending t, so a restarted fusion
server picks it up, every `resend.ResendTimer.timeout_s`: `resend_s`, or longer when answers take
longer), ingest it, go on with t+1; if its server went on without
it (a solution past t), go on with the epoch after that server's. Realtime: publish on the wall
clock (scaled by `speed`) and ingest whatever solutions have arrived; never block on the server.

Only solutions the consumers' `SolutionGate` accepts (`coplane.bus.trust`: this fleet and method,
positions on the Earth, epochs moving forward within one server generation, no impossible jumps,
only the manifest's vehicles) reach the step's plane history: a forged solution must never shape
the planes this vehicle fits.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import Counter
from pathlib import Path

from coplane.bus import (
    Answered,
    BadMessage,
    BusEvent,
    BusNode,
    KeySpace,
    Payload,
    Presence,
    Publication,
    Subscription,
    decode,
    encode,
    session_config,
)
from coplane.bus.gates import GateSet
from coplane.gnss.dgnss import DgnssCorrections
from coplane.gnss.epoch_solver import EpochResult
from coplane.gnss.standstill import load_dependencies
from coplane.gtime import GpsTime
from coplane.live.nmea_out import NmeaServer
from coplane.messages import NodeMessage, SolutionMessage
from coplane.recording.model import NavData, ObsEpoch, UwbRange
from coplane.recording.reader import open_recording
from coplane.replay import BaseCorrections, first_epoch, replay_setup, uwb_for_vehicle, vehicle_schedule
from coplane.roadmap import RoadMap
from coplane.runtime import RateLimitedLog
from coplane.steps import gps_time
from coplane.steps.map_tiles import MapReceiver
from coplane.typing import Vec

from .map_fetch import MapFetch
from .region import NODE_HISTORY, RegionKeys
from .resend import ResendTimer
from .settings import AgentSettings

log = logging.getLogger("coplane.vehicle_agent")


def _read_map(path: Path | None) -> RoadMap | None:
    """The road map as it is now (a snapshot: the fusion server extends the file as the fleet
    drives, the next run of the agent reads what it learned); None, logged, if it cannot be read."""
    if path is None:
        return None
    from coplane.store.roadmap_db import RoadMapDb

    try:
        with RoadMapDb(path, readonly=True) as db:
            road_map = db.load()
    except Exception as exc:
        log.error("road map not used: %s", exc, extra={"path": str(path)})
        return None
    log.info("road map read", extra={"path": str(path), **road_map.stats()})
    return road_map


class VehicleAgent:
    def __init__(self, settings: AgentSettings, stop: threading.Event | None = None) -> None:
        self.s = settings
        self.stop = stop or threading.Event()
        load_dependencies()  # the standstill test's, now: not at the first standing epoch
        rec = open_recording(settings.recording)
        self.rec = rec
        man = rec.manifest
        vid = man.vehicle(settings.vehicle_id).id
        setup = replay_setup(
            man,
            settings.method,
            seed=settings.seed,
            dgnss=settings.dgnss,
            fleet=settings.fleet,
            road_map=_read_map(settings.map),
        )
        self.fleet = setup.fleet
        self.keys = KeySpace(self.fleet)
        # one gate per server (with regions: its own run, its regions' vehicles; this one's: `_take`)
        regions, ids = settings.region_config() if settings.regions else None, [v.id for v in man.vehicles]
        self.gate = GateSet(self.fleet, regions, exempt=[vid], method=setup.method.name, vehicles=ids)
        self.resend = ResendTimer(settings.resend_s)
        self.step = setup.vehicle_step(rec, vid)
        self.region: RegionKeys | None = None
        if settings.regions:
            base = man.base.position_ecef_m if man.base is not None else None
            self.region = RegionKeys(self.keys, vid, settings.region_config(), base)
        self.interval_s = man.interval_s
        # the road map from the bus (map methods): the fusion server's tiles on top of --map's file
        self.tiles: MapReceiver | None = None
        self.fetch: MapFetch | None = None  # ... the tiles around the vehicle, asked as it moves
        if setup.method.plane_map:
            self.tiles = MapReceiver(self.fleet, self.step.road_map)
            self.step.road_map = self.tiles.map
            # a map file of its own stays whole; else only the box around the vehicle is kept
            self.fetch = MapFetch(
                self.keys,
                self.tiles,
                settings.map_radius_m,
                settings.map_refresh_s,
                evict=settings.map is None,
            )
        self.live = settings.gnss is not None  # a receiver stream, not the recording's file
        self.live_status: dict[str, object] = {}  # the live inputs at the end of a live run
        if self.live:
            self.schedule: list[tuple[GpsTime, ObsEpoch | None]] = []
            self.corrections = BaseCorrections({}, None, NavData())
            self.uwb: dict[GpsTime, list[UwbRange]] = {}
            self.t0: GpsTime | None = None
        else:
            self.schedule = vehicle_schedule(rec.vehicle_epochs(vid), man.interval_s)
            # only this vehicle's file, the base and uwb.csv are read: agents start fast
            self.corrections = BaseCorrections.of(rec, setup.use_dgnss)
            self.uwb = uwb_for_vehicle(rec.uwb(), vid, (t for t, _ in self.schedule), man.interval_s)
            self.t0 = first_epoch(rec)  # the fleet's first epoch: the realtime origin
        self.skipped = 0
        self.published = 0
        self.resent = 0  # lockstep: node messages put again while their epoch was unanswered
        self.ingested = 0
        self.bad_solutions = 0
        self.unplaced = 0  # regions: epochs not sent, no position to place them in a region yet
        self.home_server: str | None = None  # the server whose solution last answered this vehicle
        self.warn = RateLimitedLog(log)  # forged or bad floods must not flood the log
        # the vehicle's own fused position for the car's other systems (`live.nmea_out`)
        self.nmea: NmeaServer | None = None
        if settings.nmea_port is not None:
            self.nmea = NmeaServer([vid], settings.nmea_port)
            log.info("NMEA 0183 out", extra={"vehicle": vid, "port": self.nmea.ports[vid]})

    def node(self) -> BusNode:
        """This agent's place on the bus: its node key out, the fleet solution in, its token."""
        vid = self.step.vehicle_id
        return BusNode(
            session_config("client", self.s.connect, lease_ms=self.s.lease_ms),
            token=self.keys.alive("agent", vid),
            # history: a restarted fusion server still receives the last 120 (docs/reliability/durability.md);
            # with regions the node keys follow the vehicle (`node_keys`)
            publish=[]
            if self.region is not None
            else [Publication(self.keys.node(vid), must_deliver=True, history=NODE_HISTORY)],
            history_later=self.region is not None,
            subscribe=[
                Subscription(self.keys.all_solutions),
                # the servers' tokens: a restarted server's solutions are taken at once (`GateSet`)
                Subscription(self.keys.all_alive("fusion"), liveliness=True),
            ],
        )

    @property
    def untrusted(self) -> Counter[str]:
        """Solutions (and vehicles in them) the gate kept out of the plane history, by reason."""
        return self.gate.counts

    def ingest_one(self, ev: BusEvent, expect: GpsTime | None = None) -> SolutionMessage | None:
        """Decode, gate and ingest one bus event; the solution taken, or None. `expect`: this
        agent's current epoch (solutions far beyond it are forged; a gap before it is no reason to
        reject the one a lockstep agent waits for)."""
        if isinstance(ev, Presence):
            # a fusion server withdrew its token: a restarted server's first solution, held
            # while the old run was not over, is taken now
            released = self.gate.on_token(ev.key, ev.alive, time.time())
            return None if released is None else self._take(released, released)
        if isinstance(ev, Answered):
            if self.fetch is not None:
                self.fetch.finish(ev, time.monotonic())
            return None
        if not isinstance(ev, Payload):
            return None
        if (tiles_from := KeySpace.server_of_tiles_key(ev.key)) is not None:
            if self.fetch is not None:  # an answer to this agent's map request
                self.fetch.take(ev.data, tiles_from, self.warn)
            return None
        try:
            sol = decode(SolutionMessage, ev.data)
        except BadMessage as exc:
            self.bad_solutions += 1
            self.warn.log(
                logging.WARNING,
                ("payload", exc.kind),
                "rejected solution payload",
                {"reason": str(exc), "count": self.bad_solutions},
            )
            return None
        server = KeySpace.server_of_solution_key(ev.key)
        return self._take(self.gate.check(server, sol, time.time(), expect).solution, sol)

    def node_keys(self, node: BusNode, msg: NodeMessage) -> list[str]:
        """The keys to put this epoch's node message on: the vehicle's own, or with regions its
        region's and the copies near a boundary (empty: no position yet, the message is not sent).
        The first is the one a lockstep agent re-sends on."""
        if self.region is None:
            return [self.keys.node(self.step.vehicle_id)]
        keys = self.region.keys_for(msg, node)
        if not keys:
            self.unplaced += 1
        return keys

    def answered(self, sol: SolutionMessage, t: GpsTime) -> bool:
        """Whether a lockstep agent waiting at `t` may go on: the solution answers this vehicle's
        epoch `t` (or a later one); with regions, a solution two epochs past `t` from any server
        also does (the fleet went on without this vehicle, e.g. its message came too late)."""
        st = gps_time(sol.epoch)
        if st < t:
            return False
        return sol.answers(self.step.vehicle_id) or st - t >= 2 * self.interval_s

    def front_end(
        self, node: BusNode, t: GpsTime, ep: ObsEpoch | None, corrections: DgnssCorrections | None
    ) -> EpochResult:
        """This epoch's SPP and Doppler and, for a map method, the road map around the fix asked
        for (`MapFetch`); the first answer is awaited (up to `map_wait_s`), so the first epochs
        already use the map."""
        front = self.step.front_end(t, ep, corrections)
        if self.fetch is not None and front.spp.ok:
            first = self.fetch.box is None
            if self.fetch.follow(node, front.spp.position, time.monotonic()) and first:
                self.wait_for_map(node, front.spp.position)
        return front

    def wait_for_map(self, node: BusNode, position: Vec) -> None:
        """Wait (up to `map_wait_s`) until a server answered the first map request, asking again
        while none has (a server still starting); solutions that arrive meanwhile are ingested."""
        assert self.fetch is not None and self.tiles is not None
        deadline = time.monotonic() + self.s.map_wait_s
        while not self.fetch.held and not self.stop.is_set() and time.monotonic() < deadline:
            if (ev := node.get(timeout=0.05)) is not None:
                self.ingest_one(ev)
            elif self.fetch.pending is None:
                self.fetch.follow(node, position, time.monotonic())
        log.info(
            "road map from the bus" if self.fetch.held else "no road map from the bus yet",
            extra={"vehicle": self.step.vehicle_id, **self.tiles.map.stats(), **dict(self.tiles.counts)},
        )

    def _take(self, taken: SolutionMessage | None, offered: SolutionMessage) -> SolutionMessage | None:
        """Ingest what the gate let through; count and (rate-limited) log what it did not, and
        with regions a solution that speaks for this vehicle from a server that does not own its
        region (`RegionKeys.may_answer`, counted `not-owner`)."""
        region = self.region
        if (
            taken is not None
            and region is not None
            and not region.may_answer(taken, self.gate.servers_alive, self.gate.settled())
        ):
            self.gate.overflow["not-owner"] += 1
            self.gate.last_reason, taken = "not-owner", None
        if taken is None:
            reason = self.gate.last_reason or "untrusted"
            n = self.gate.counts[reason]
            if reason not in ("repeat", "wrong-fleet"):
                self.warn.log(
                    logging.WARNING,
                    ("untrusted", reason),
                    "untrusted solution ignored",
                    {"reason": reason, "seq": offered.seq, "generation": offered.generation, "count": n},
                )
            return None
        self.step.ingest(taken)
        self.ingested += 1
        if self.nmea is not None:
            self.nmea.publish(taken)
        return taken

    def run(self) -> int:
        """Replay the whole schedule (or, with --gnss, follow the live streams until they end or
        the agent is stopped); returns the number of node messages published."""
        try:
            return self._run()
        finally:
            if self.nmea is not None:
                self.nmea.close()  # its clients see the end of their streams

    def _run(self) -> int:
        if self.live:
            from .live import run_live

            return run_live(self)
        s = self.s
        with self.node() as node:
            log.info(
                "agent started",
                extra={"vehicle": self.step.vehicle_id, "epochs": len(self.schedule), "pace": s.pace},
            )
            if not self.schedule:
                return 0
            start = s.start_unix_s if s.start_unix_s is not None else time.time()
            t0 = self.t0 or self.schedule[0][0]
            interval = self.rec.manifest.interval_s
            behind: GpsTime | None = None  # lockstep: the fleet's epoch when it went on without us
            for t, ep in self.schedule:
                if self.stop.is_set():
                    break
                if behind is not None and not behind < t:
                    # its epochs up to the fleet's are solved already: sent, they would only be late,
                    # and the agent would stay two epochs behind the fleet for good
                    self.skipped += 1
                    continue
                if s.pace == "realtime":
                    due = start + (t - t0) / s.speed
                    if due < time.time() - interval / s.speed:
                        self.skipped += 1  # already past: a (re)started agent joins at the current epoch
                        continue
                    if self.stop.wait(max(0.0, due - time.time())):
                        break
                for ev in node.drain():  # ingest what has arrived, in order
                    self.ingest_one(ev, expect=t)
                corrections = self.corrections.at(t)
                front = self.front_end(node, t, ep, corrections)
                msg = self.step.process(t, ep, corrections, self.uwb.get(t, ()), front)
                msg = msg.model_copy(update={"sent_unix_s": time.time()})  # latency stamp only
                if not (keys := self.node_keys(node, msg)):
                    continue
                payload = encode(msg)
                for key in keys:
                    node.put(key, payload)
                self.published += 1
                if s.pace == "lockstep":
                    behind = self.wait_for_solution(t, node, keys, payload)
                    if behind is not None:  # rate-limited: a vehicle always rejected would repeat it
                        self.warn.log(
                            logging.WARNING,
                            ("behind",),
                            "the fleet went on without this vehicle: joining at its next epoch",
                            {"vehicle": self.step.vehicle_id, "epoch": str(t), "fleet_epoch": str(behind)},
                        )
            if s.pace == "realtime" and self.published and not self.stop.is_set():
                self.await_last_solution(node, self.schedule[-1][0], 2.0 + 3.0 * interval / s.speed)
            log.info(
                "agent finished",
                extra={
                    "vehicle": self.step.vehicle_id,
                    "published": self.published,
                    "skipped": self.skipped,
                    "resent": self.resent,
                    "resend_timeout_s": round(self.resend.timeout_s(), 3),
                    **(self.fetch.status() if self.fetch is not None else {}),
                },
            )
            return self.published

    def await_last_solution(self, node: BusNode, t_last: GpsTime, timeout_s: float) -> None:
        """Realtime end: stay on the bus until the last epoch's solution arrives (or `timeout_s`).
        Closing the session right after the last put could drop that message in the transport
        before it left (seen in CI: a vehicle's last epoch missing at the server)."""
        deadline = time.monotonic() + timeout_s
        while not self.stop.is_set() and time.monotonic() < deadline:
            ev = node.get(timeout=0.05)
            if ev is None:
                continue
            sol = self.ingest_one(ev)
            if sol is not None and not (gps_time(sol.epoch) < t_last):
                return

    def wait_for_solution(self, t: GpsTime, node: BusNode, keys: list[str], payload: bytes) -> GpsTime | None:
        """Lockstep: wait until a solution answers epoch `t` (re-sending it); the epoch of the
        solution that released this agent without answering it, if it came from the server that
        answers this vehicle (the fleet went on without this vehicle, see `answered`), else None."""
        start = last_send = time.monotonic()
        while not self.stop.is_set():
            ev = node.get(timeout=0.05)
            sol = None
            if ev is not None:
                sol = self.ingest_one(ev, expect=t)
            elif (released := self.gate.release(time.time())) is not None:
                # a restarted server's first solution, held until the old one went quiet
                sol = self._take(released, released)
            elif time.monotonic() - last_send > self.resend.timeout_s():
                for key in keys:
                    node.put(key, payload)  # the server dedups; a restarted server needs it
                self.resent += 1
                last_send = time.monotonic()
            if sol is not None and self.answered(sol, t):
                st = gps_time(sol.epoch)
                if st == t and sol.answers(self.step.vehicle_id):
                    self.home_server = sol.server
                    self.resend.answered(time.monotonic() - start)
                    return None
                # past `t` on the server that answers this vehicle: it went on without it (with
                # regions another server's fleet may just be ahead of this one's)
                return st if st > t and sol.server == self.home_server else None
        return None
