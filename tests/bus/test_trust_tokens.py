"""Ending a server's run by its liveliness token (`GateSet.presence`) through a live router: only
the session that declared a token can make it go away. A forger on an insecure bus that declares
the same key and withdraws it changes nothing (Zenoh's router keeps a key alive while any session
declares it), so the genuine server's run ends only when that server's own token goes."""

from __future__ import annotations

import time

import zenoh
from support.api import FLEET, T0, ecef_at, solution, vehicle_state

from coplane.bus import KeySpace, router_config, session_config
from coplane.bus.gates import GateSet
from coplane.bus.security import BusSecurity
from coplane.fleet import free_port
from coplane.messages import SolutionMessage

INSECURE = BusSecurity(insecure=True)


def _sol(k: int, gen: str) -> SolutionMessage:
    s = solution(k, T0 + float(k), [vehicle_state("a", ecef_at(0, 0))])
    return s.model_copy(update={"generation": gen})


def _wait(cond: object, timeout: float = 10.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if cond():  # type: ignore[operator]
            return True
        time.sleep(0.02)
    return False


def test_a_forgers_twin_token_cannot_end_the_genuine_run() -> None:
    keys = KeySpace(FLEET)
    ep = f"tcp/127.0.0.1:{free_port()}"
    router = zenoh.open(router_config([ep], security=INSECURE))
    sessions = [zenoh.open(session_config("client", [ep], security=INSECURE)) for _ in range(3)]
    consumer, genuine, forger = sessions
    gates = GateSet(FLEET, restart_quiet_s=60.0)  # only a token can end the run in this test
    events: list[bool] = []

    def on_token(sample: zenoh.Sample) -> None:
        alive = sample.kind == zenoh.SampleKind.PUT
        gates.presence(str(sample.key_expr), alive)
        events.append(alive)

    try:
        consumer.liveliness().declare_subscriber(keys.all_alive("fusion"), on_token, history=True)
        assert gates.check("", _sol(0, "00c0ffee00c0ffee"), time.time()).accepted
        token = genuine.liveliness().declare_token(keys.alive("fusion", "0"))  # noqa: F841 (kept alive)
        assert _wait(lambda: events == [True])
        twin = forger.liveliness().declare_token(keys.alive("fusion", "0"))
        time.sleep(0.5)
        twin.undeclare()
        time.sleep(1.0)
        assert events == [True], "the router announced the forger's twin token's coming or going"
        forged = _sol(0, "badbadbadbadbad0")
        assert gates.check("", forged, time.time()).reason == "new-generation"
        genuine.close()  # the genuine server stops: its token goes
        assert _wait(lambda: events == [True, False])
        restarted = _sol(0, "0123456789abcdef")
        v = gates.check("", restarted, time.time())
        assert v.accepted and v.reset
    finally:
        for s in sessions:
            s.close()
        router.close()
