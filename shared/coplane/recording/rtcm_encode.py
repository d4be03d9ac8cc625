"""Building RTCM 3 frames from pyrtcm's own message definitions.

pyrtcm parses RTCM 3 but builds a message only from payload bytes. Rather than a second, hand-kept
copy of the bit layouts, this module walks the same payload definition pyrtcm parses with
(`RTCM_PAYLOADS_GET[_MSM]`) and the same data-field table (`RTCM_DATA_FIELDS`: type, width,
scale), and packs integer field values in that order; `RTCMMessage(payload).serialize()` adds
the header and CRC-24Q. So whatever pyrtcm reads back is, by construction, what was meant, and
rtcm3.py checks each built frame by parsing it.

Values are raw integers (the field in units of its LSB), named as pyrtcm names the parsed
attributes: "DF004", per satellite "DF397_03", per cell "DF405_07". Masks DF394/DF395/DF396 set
the satellite, signal and cell counts exactly as in pyrtcm's parser.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from pyrtcm import RTCMMessage
from pyrtcm.rtcmtypes_core import (
    BIT,
    BITX,
    CELPRN,
    CELSIG,
    INT,
    INTS,
    NCELL,
    NSAT,
    NSIG,
    PRN,
    RTCM_DATA_FIELDS,
    UINT,
)
from pyrtcm.rtcmtypes_get import RTCM_PAYLOADS_GET
from pyrtcm.rtcmtypes_get_msm import RTCM_PAYLOADS_GET_MSM


class FieldRangeError(ValueError):
    """A value does not fit its RTCM data field."""


def _definition(identity: str) -> dict[str, Any]:
    d = RTCM_PAYLOADS_GET_MSM.get(identity) or RTCM_PAYLOADS_GET.get(identity)
    if not d:
        raise ValueError(f"pyrtcm has no definition of RTCM message {identity}")
    return d


def _bits(value: int, width: int, atyp: str, name: str) -> int:
    """The field's bit pattern (two's complement, sign-magnitude or unsigned)."""
    if atyp == INT:
        lo, hi = -(1 << (width - 1)), (1 << (width - 1)) - 1
        if not lo <= value <= hi:
            raise FieldRangeError(f"{name}={value} outside {lo}..{hi}")
        return value & ((1 << width) - 1)
    if atyp == INTS:
        mag = abs(value)
        if mag >= 1 << (width - 1):
            raise FieldRangeError(f"{name}={value} outside +-{(1 << (width - 1)) - 1}")
        return ((1 << (width - 1)) if value < 0 else 0) | mag
    if atyp in (UINT, BIT, BITX):
        if not 0 <= value < 1 << width:
            raise FieldRangeError(f"{name}={value} outside 0..{(1 << width) - 1}")
        return value
    raise ValueError(f"{name}: field type {atyp} is not written")


def build_payload(identity: str, values: Mapping[str, int]) -> bytes:
    """Pack `values` in pyrtcm's field order for message `identity` (missing fields are 0)."""
    acc = 0
    nbits = 0
    counts: dict[str, int] = {}

    def put(name: str, key: str) -> None:
        nonlocal acc, nbits
        atyp, width, _res, _desc = RTCM_DATA_FIELDS[name]
        if atyp in (PRN, CELPRN, CELSIG):
            return  # derived by the parser from the masks, not in the payload
        if name == "DF396":
            width = counts[NSAT] * counts[NSIG]
        v = int(identity) if name == "DF002" else int(values.get(key, 0))
        acc = (acc << width) | _bits(v, width, atyp, key)
        nbits += width
        if name == "DF394":
            counts[NSAT] = bin(v).count("1")
        elif name == "DF395":
            counts[NSIG] = bin(v).count("1")
        elif name == "DF396":
            counts[NCELL] = bin(v).count("1")

    def walk(d: Mapping[str, Any], index: tuple[int, ...]) -> None:
        for name, adef in d.items():
            if name.endswith("_grp"):
                size, group = adef
                n = size if isinstance(size, int) else counts.get(size, int(values.get(size, 0)))
                for i in range(1, n + 1):
                    walk(group, (*index, i))
            else:
                put(name, name + "".join(f"_{i:02d}" for i in index))

    walk(_definition(identity), ())
    pad = (-nbits) % 8
    return (acc << pad).to_bytes((nbits + pad) // 8, "big")


def build_frame(identity: str, values: Mapping[str, int]) -> bytes:
    """A complete RTCM 3 frame (preamble, length, payload, CRC-24Q) via pyrtcm."""
    return RTCMMessage(payload=build_payload(identity, values)).serialize()
