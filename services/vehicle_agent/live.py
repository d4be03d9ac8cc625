"""The agent on live streams (`--gnss`, `--base`, `--uwb`): epochs as the receiver delivers them.

Each receiver epoch is put on the fleet's nominal grid (first epoch per nominal time; others are
counted), processed by the same `VehicleStep` as a replay and published. Lockstep (a log replayed
through the live path): the agent waits for each epoch's fleet solution and fills the nominal
epochs a receiver log lacks with empty ones, as the replay schedule does, so the answers equal
the replay's. Realtime (a receiver on the road): no wait, no fill; an epoch that is not after the
last one (a receiver that restarted, a time jump back) is dropped and counted. A stream that
drops is reconnected by its source; meanwhile the vehicle sends nothing, and the fusion server
does not wait for it: after OFFLINE_AFTER_S without an epoch the agent withdraws its liveliness
token (the vehicle goes offline for the fleet) and declares it again with the next epoch.
"""

from __future__ import annotations

import logging
import time
from typing import TYPE_CHECKING

from coplane.bus import BusNode, encode
from coplane.errors import ConfigError
from coplane.gtime import GpsTime
from coplane.live.inputs import END, LiveInputs, LiveOptions
from coplane.live.urls import parse_source
from coplane.recording.model import ObsEpoch

if TYPE_CHECKING:
    from .agent import VehicleAgent

log = logging.getLogger("coplane.vehicle_agent")
MAX_FILL_EPOCHS = 600  # lockstep: a receiver log gap longer than this is not filled epoch by epoch
STATUS_EVERY_S = 10.0
# realtime: a receiver silent this long (and this many intervals) takes the vehicle off the bus
OFFLINE_AFTER_S = 3.0
OFFLINE_AFTER_EPOCHS = 3


def live_inputs(agent: VehicleAgent) -> LiveInputs:
    """The agent's sources, validated (a ConfigError names the option and the part that is wrong)."""
    s, man = agent.s, agent.rec.manifest
    assert s.gnss is not None
    gnss = parse_source(s.gnss, option="--gnss", role="gnss")
    base = parse_source(s.base, option="--base", role="base") if s.base else None
    uwb = parse_source(s.uwb, option="--uwb", role="uwb") if s.uwb else None
    if base is not None and s.dgnss is False:
        raise ConfigError("--base was given with --dgnss false: drop one of them")
    return LiveInputs(
        agent.step.vehicle_id,
        [v.id for v in man.vehicles],
        gnss,
        agent.step.nav,
        LiveOptions(
            interval_s=man.interval_s,
            lockstep=s.pace == "lockstep",
            max_correction_age_s=s.max_correction_age_s,
            align_wait_s=s.align_wait_s,
        ),
        base=base,
        base_position_ecef_m=man.base.position_ecef_m if man.base is not None else None,
        uwb=uwb,
        uwb_max_range_m=man.uwb.max_range_m if man.uwb is not None else None,
    )


def run_live(agent: VehicleAgent) -> int:
    """Follow the streams until the receiver stream ends or the agent is stopped."""
    inputs = live_inputs(agent)
    interval = agent.rec.manifest.interval_s
    lockstep = agent.s.pace == "lockstep"
    last_t: GpsTime | None = None
    last_epoch_at = time.monotonic()
    offline_after = max(OFFLINE_AFTER_S, OFFLINE_AFTER_EPOCHS * interval)
    next_status = time.monotonic() + STATUS_EVERY_S
    with agent.node() as node:
        log.info(
            "agent started on live streams",
            extra={"vehicle": agent.step.vehicle_id, "pace": agent.s.pace, **inputs.status()},
        )
        inputs.start(agent.stop)
        while not agent.stop.is_set():
            for ev in node.drain():
                agent.ingest_one(ev, expect=last_t)
            if time.monotonic() >= next_status:
                next_status = time.monotonic() + STATUS_EVERY_S
                log.info("live inputs", extra={"vehicle": agent.step.vehicle_id, **inputs.status()})
            got = inputs.next_epoch(timeout=0.2)
            if got is END:
                break
            if not isinstance(got, ObsEpoch):
                if not lockstep and node.present and time.monotonic() - last_epoch_at > offline_after:
                    node.set_present(False)  # the fleet stops waiting for this vehicle
                    log.warning(
                        "receiver silent: vehicle offline",
                        extra={"vehicle": agent.step.vehicle_id, "silent_s": round(offline_after, 1)},
                    )
                continue
            last_epoch_at = time.monotonic()
            if not node.present:
                node.set_present(True)
                log.info("receiver back: vehicle online", extra={"vehicle": agent.step.vehicle_id})
            t = got.time.round_to(interval)
            if last_t is not None and t <= last_t:
                agent.skipped += 1  # a second receiver epoch of one nominal epoch, or time going back
                continue
            todo: list[tuple[GpsTime, ObsEpoch | None]] = []
            if lockstep and last_t is not None and round((t - last_t) / interval) - 1 <= MAX_FILL_EPOCHS:
                todo += [
                    ((last_t + k * interval).round_to(interval), None)
                    for k in range(1, round((t - last_t) / interval))
                ]
            todo.append((t, got))
            for tt, ep in todo:
                _publish(agent, node, inputs, tt, ep, lockstep)
            last_t = t
        if not lockstep and agent.published and not agent.stop.is_set() and last_t is not None:
            agent.await_last_solution(node, last_t, 2.0 + 3.0 * interval)
        log.info(
            "agent finished",
            extra={
                "vehicle": agent.step.vehicle_id,
                "published": agent.published,
                "skipped": agent.skipped,
                **(agent.fetch.status() if agent.fetch is not None else {}),
                **inputs.status(),
            },
        )
    agent.live_status = inputs.status()
    return agent.published


def _publish(
    agent: VehicleAgent,
    node: BusNode,
    inputs: LiveInputs,
    t: GpsTime,
    ep: ObsEpoch | None,
    lockstep: bool,
) -> None:
    """One nominal epoch: corrections and ranges lined up with it, the step, the bus."""
    corrections = inputs.corrections(t)
    ranges = inputs.ranges(t)
    for ev in node.drain():
        agent.ingest_one(ev, expect=t)
    msg = agent.step.process(t, ep, corrections, ranges, agent.front_end(node, t, ep, corrections))
    msg = msg.model_copy(update={"sent_unix_s": time.time()})
    if not (keys := agent.node_keys(node, msg)):
        return
    payload = encode(msg)
    for key in keys:
        node.put(key, payload)
    agent.published += 1
    if lockstep:
        agent.wait_for_solution(t, node, keys, payload)
