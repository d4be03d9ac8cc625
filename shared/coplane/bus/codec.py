"""Bus payloads <-> pydantic wire models (coplane.messages), with one error type for bad input.

Nothing a payload contains may raise anything but `BadMessage` into a service's main loop, so
hostile or broken publishers only ever show up as counted rejects (docs/bus.md, Messages).
"""

from __future__ import annotations

from typing import Any, TypeVar

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


def decode(model: type[M], payload: bytes, max_bytes: int = MAX_PAYLOAD_BYTES) -> M:
    """Validate a payload into `model`; raises BadMessage with a short reason, never anything else."""
    if len(payload) > max_bytes:
        raise BadMessage("too-large", f"{len(payload)} bytes > {max_bytes}")
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


def payload_bytes(sample: Any) -> bytes:
    """The payload of a Zenoh sample as bytes (copied: the sample's buffer is Zenoh's)."""
    return bytes(sample.payload.to_bytes())
