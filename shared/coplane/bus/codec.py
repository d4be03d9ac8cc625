"""Bus payloads <-> pydantic wire models (coplane.messages), with one error type for bad input.

Nothing a payload contains may raise anything but `BadMessage` into a service's main loop, so
hostile or broken publishers only ever show up as counted rejects (docs/bus.md, Messages).
"""

from __future__ import annotations

import hashlib
from typing import Any, Generic, TypeVar

from pydantic import BaseModel, ValidationError

M = TypeVar("M", bound=BaseModel)

MAX_PAYLOAD_BYTES = 1 << 20


def encode(msg: BaseModel) -> bytes:
    """The JSON bytes of a wire model (floats round-trip exactly, so replays stay bit-identical)."""
    return msg.model_dump_json(by_alias=True).encode()


class BadMessage(Exception):
    """A payload that failed validation; `kind` is a stable slug for metrics."""

    def __init__(self, kind: str, reason: str) -> None:
        super().__init__(f"{kind}: {reason}")
        self.kind = kind
        self.reason = reason


def check_size(payload: bytes, max_bytes: int = MAX_PAYLOAD_BYTES) -> None:
    """Raise BadMessage("too-large") for a payload over `max_bytes`, before any work on it."""
    if len(payload) > max_bytes:
        raise BadMessage("too-large", f"{len(payload)} bytes > {max_bytes}")


def decode(model: type[M], payload: bytes, max_bytes: int = MAX_PAYLOAD_BYTES) -> M:
    """Validate a payload into `model`; raises BadMessage with a short reason, never anything else."""
    check_size(payload, max_bytes)
    try:
        return model.model_validate_json(payload)
    except ValidationError as exc:
        errs = exc.errors()
        if not errs:
            raise BadMessage("invalid-message", str(exc)[:300]) from None
        first = errs[0]
        loc = ".".join(str(x) for x in first["loc"])
        kind = "invalid-json" if first["type"] == "json_invalid" else "invalid-message"
        raise BadMessage(kind, f"{loc}: {first['msg']}"[:300]) from None
    except Exception as exc:  # any parser surprise is still just a bad message
        raise BadMessage("invalid-message", repr(exc)[:300]) from None


class RepeatDecoder(Generic[M]):
    """`decode` that keeps each sender's last decoded payload, so a byte-identical re-send is not
    validated again (a lockstep agent re-sends its node message every second until answered: with
    epochs that take seconds to solve, most of a server's decoding was re-sends). Same bytes, same
    model: what the caller does with it is unchanged, and a payload that failed is never kept."""

    def __init__(self, model: type[M]) -> None:
        self.model = model
        self._last: dict[str, tuple[bytes, M]] = {}

    @staticmethod
    def digest(payload: bytes) -> bytes:
        """The payload's 16-byte BLAKE2b digest (also what admission tells duplicates by)."""
        return hashlib.blake2b(payload, digest_size=16).digest()

    def decode(self, sender: str, payload: bytes) -> tuple[M, bytes]:
        """The model of `payload` and its `digest`, the model from `sender`'s last one when the
        bytes are the same; raises BadMessage like `decode`, an oversized payload before it is
        hashed (a hostile sender must not make the server hash megabytes)."""
        check_size(payload)
        digest = self.digest(payload)
        last = self._last.get(sender)
        if last is not None and last[0] == digest:
            return last[1], digest
        msg = decode(self.model, payload)
        self._last[sender] = (digest, msg)
        return msg, digest


def payload_bytes(sample: Any) -> bytes:
    """The payload of a Zenoh sample as bytes (copied: the sample's buffer is Zenoh's)."""
    return bytes(sample.payload.to_bytes())
