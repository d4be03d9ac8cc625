"""The bus: the Zenoh key space, payload codec, session configs and the `BusNode` every service
uses (docs/bus.md). `python -m coplane.bus.router` runs a router."""

from coplane.bus.codec import BadMessage, decode, encode, payload_bytes
from coplane.bus.config import router_config, session_config
from coplane.bus.keys import KEY_ROOT, KeySpace
from coplane.bus.node import BusEvent, BusNode, Payload, Presence, Publication, Subscription

__all__ = [
    "KEY_ROOT",
    "BadMessage",
    "BusEvent",
    "BusNode",
    "KeySpace",
    "Payload",
    "Presence",
    "Publication",
    "Subscription",
    "decode",
    "encode",
    "payload_bytes",
    "router_config",
    "session_config",
]
