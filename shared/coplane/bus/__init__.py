"""The bus: the Zenoh key space, payload codec, session configs, security (certificates, identities,
access control) and the `BusNode` every service uses (docs/bus.md). `python -m coplane.bus.router`
runs a router."""

from coplane.bus.codec import BadMessage, RepeatDecoder, decode, encode, payload_bytes
from coplane.bus.config import router_config, router_document, secure_endpoint, session_config
from coplane.bus.keys import KEY_ROOT, KeySpace
from coplane.bus.node import (
    Answered,
    BusEvent,
    BusNode,
    Payload,
    Presence,
    Publication,
    Request,
    Subscription,
)
from coplane.bus.security import (
    API,
    FUSION,
    INSECURE_WARNING,
    MONITOR,
    ROUTER,
    BusSecurity,
    current_security,
    use_security,
    vehicle_identity,
)

__all__ = [
    "API",
    "FUSION",
    "INSECURE_WARNING",
    "KEY_ROOT",
    "MONITOR",
    "ROUTER",
    "Answered",
    "BadMessage",
    "BusEvent",
    "BusNode",
    "BusSecurity",
    "KeySpace",
    "Payload",
    "Presence",
    "Publication",
    "RepeatDecoder",
    "Request",
    "Subscription",
    "current_security",
    "decode",
    "encode",
    "payload_bytes",
    "router_config",
    "router_document",
    "secure_endpoint",
    "session_config",
    "use_security",
    "vehicle_identity",
]
