"""Which fusion server owns which region (docs/scale.md): from each server's diagnostics."""

from __future__ import annotations

from fastapi import APIRouter

from ..deps import StateDep
from ..models import RegionOwnership, ServerRegions

router = APIRouter(tags=["regions"])


@router.get(
    "/regions",
    response_model=RegionOwnership,
    summary="The fusion servers, the shards each owns and the regions (with their vehicles) each solves",
)
async def regions(state: StateDep) -> RegionOwnership:
    servers = []
    for name, d in sorted(state.server_diagnostics.items()):
        servers.append(
            ServerRegions(
                server=d.server or name or "0",
                alive=(d.server or name or "0") in state.fusion_alive,
                shards=list(d.shards),
                regions={r: list(vs) for r, vs in sorted(d.regions.items())},
                epochs_solved=d.epochs_solved,
            )
        )
    alive = sorted(state.fusion_alive)
    claims: dict[int, int] = {}
    for s in servers:
        if s.alive:
            for k in s.shards:
                claims[k] = claims.get(k, 0) + 1
    # every server computes the same split from the live servers alone; a shard claimed twice
    # means two servers see different live sets (a moment during a change, or a partition)
    overlaps = sorted(k for k, n in claims.items() if n > 1)
    return RegionOwnership(servers=servers, live_servers=alive, overlapping_shards=overlaps)
