"""HTTP routers, one module per concern; they take what they need from `..deps` and never touch the bus."""

from __future__ import annotations

from typing import Any

from ..models import Problem


def problems(*codes: int) -> dict[int | str, dict[str, Any]]:
    """OpenAPI entries for error responses (the app rewrites them to application/problem+json)."""
    text = {
        404: "Not found (an unknown vehicle, no road map configured)",
        422: "Invalid parameters",
        503: "Unavailable (too many clients, shutting down, the road map file unreadable)",
    }
    return {c: {"model": Problem, "description": text.get(c, "Error")} for c in codes}
