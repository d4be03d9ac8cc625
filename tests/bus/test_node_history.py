"""BusNode publication caches and history subscriptions (what a restarted fusion server relies on)."""

from __future__ import annotations

import time

import zenoh

from coplane.bus import BusNode, Payload, Publication, Subscription, router_config, session_config
from coplane.fleet import free_port


def _events(node: BusNode, n: int, timeout: float = 10.0) -> list[bytes]:
    out: list[bytes] = []
    deadline = time.monotonic() + timeout
    while len(out) < n and time.monotonic() < deadline:
        ev = node.get(timeout=0.05)
        if isinstance(ev, Payload):
            out.append(ev.data)
    return out


def test_a_late_history_subscriber_gets_the_cache_then_live_samples() -> None:
    ep = f"tcp/127.0.0.1:{free_port()}"
    router = zenoh.open(router_config([ep]))
    try:
        key = "t/v1/f/vehicle/u1/node"
        with BusNode(session_config("client", [ep]), publish=[Publication(key, True, history=3)]) as pub:
            for i in range(5):
                pub.put(key, f"m{i}".encode())
            time.sleep(0.3)
            late = BusNode(
                session_config("client", [ep]),
                subscribe=[Subscription("t/v1/f/vehicle/*/node", history=True)],
            )
            plain = BusNode(session_config("client", [ep]), subscribe=[Subscription("t/v1/f/vehicle/*/node")])
            with late, plain:
                assert _events(late, 3) == [b"m2", b"m3", b"m4"]  # the last 3, in order
                time.sleep(0.3)
                pub.put(key, b"live")
                assert _events(late, 1) == [b"live"]
                assert _events(plain, 1) == [b"live"]  # a plain subscriber hears only what follows
    finally:
        router.close()
