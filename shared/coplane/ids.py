"""Identifier rules shared by every boundary (recording manifests, the bus, the HTTP API)."""

from __future__ import annotations

import re

# A vehicle or fleet id: a Zenoh key chunk, a file stem and a URL path segment at once.
VEHICLE_ID_PATTERN = r"^[A-Za-z0-9_-]{1,32}$"
VEHICLE_ID = re.compile(VEHICLE_ID_PATTERN)


def is_vehicle_id(text: str) -> bool:
    """True for a valid id; unlike `VEHICLE_ID.match`, "u1\\n" is not one (`$` matches before a final newline)."""
    return VEHICLE_ID.fullmatch(text) is not None
