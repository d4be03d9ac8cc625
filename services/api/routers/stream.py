"""Server-Sent Events of fleet solutions (FastAPI's built-in EventSourceResponse).

Each client first gets the latest solution (if any), then one `solution` event per solved epoch;
`id` is the solution's seq. A slow client loses its oldest events rather than slowing anyone.
"""

from __future__ import annotations

from collections.abc import AsyncIterator
from typing import Annotated

from fastapi import APIRouter, Depends, HTTPException
from fastapi.sse import EventSourceResponse, ServerSentEvent

from ..deps import HubDep
from ..hub import StreamHub
from . import problems

router = APIRouter(tags=["stream"])


def _slot(h: HubDep) -> StreamHub:
    """Refuse before the stream starts (a status code cannot change once events flow)."""
    if h.full:
        raise HTTPException(503, f"at most {h.max_clients} stream clients, or the API is stopping")
    return h


@router.get(
    "/stream",
    response_class=EventSourceResponse,
    responses={
        200: {
            "description": (
                "text/event-stream; each `solution` event's data is a StreamEvent (JSON), id = seq"
            ),
            "content": {"text/event-stream": {}},
        },
        **problems(503),
    },
    summary="Live solutions as Server-Sent Events",
)
async def stream(h: Annotated[StreamHub, Depends(_slot)]) -> AsyncIterator[ServerSentEvent]:
    q = h.subscribe()
    try:
        while True:
            item = await q.get()
            if item is None:
                return
            seq, data = item
            yield ServerSentEvent(raw_data=data, event="solution", id=str(seq))
    finally:
        h.unsubscribe(q)
