"""Which live fusion server owns a shard: rendezvous (highest-random-weight) hashing.

Every server and every consumer computes `owner(shard, live servers)` from the servers'
liveliness tokens alone, so they agree without a coordinator or an election. When a server goes,
only its shards move (each to the survivor with the next-highest weight); when one joins, it takes
about 1/N of the shards, from every server alike. Consistent hashing on a ring needs virtual nodes
for the same balance; rendezvous hashing needs only a hash (Thaler and Ravishankar, 1998).
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterable, Sequence
from collections.abc import Set as AbstractSet

import numpy as np
from numpy.typing import ArrayLike

from coplane.roadmap.grid import tiles_around

from .config import RegionConfig
from .grid import shard_of

# after a change of the live servers (and at start, while they find one another) the processes'
# views of who owns what may differ for a moment: within this time of a change, servers take any
# server's tiles and agents take any server's answer for their vehicle
MOVE_GRACE_S = 30.0


def _weight(server: str, item: str) -> int:
    h = hashlib.blake2b(f"{server}\x00{item}".encode(), digest_size=8).digest()
    return int.from_bytes(h, "big")


def owner(item: str | int, servers: Iterable[str]) -> str | None:
    """The server with the highest weight for `item` (ties, never seen with 64-bit weights, go to
    the smaller server id); None when there is no server."""
    best: tuple[int, str] | None = None
    for s in servers:
        w = (_weight(s, str(item)), s)
        if best is None or w[0] > best[0] or (w[0] == best[0] and s < best[1]):
            best = w
    return None if best is None else best[1]


def owned_shards(server: str, servers: Iterable[str], shards: int) -> set[int]:
    """The shards `server` owns among `servers` (it counts itself even if not yet listed)."""
    live = sorted(set(servers) | {server})
    return {s for s in range(shards) if owner(s, live) == server}


def assignment(servers: Sequence[str], shards: int) -> dict[int, str]:
    """Every shard's owner (empty when no server is live): what the API shows."""
    live = sorted(set(servers))
    if not live:
        return {}
    return {s: owner(s, live) or "" for s in range(shards)}


def may_speak_of(ecef: ArrayLike, shards: AbstractSet[int], cfg: RegionConfig) -> bool:
    """Whether a server that owns `shards` (`owned_shards`) may publish a vehicle state at `ecef`:
    a region within `margin_m` + `hysteresis_m` of it is in one of them. A server publishes the
    vehicles of its own regions only (their home region comes from the agent's SPP fix, held by
    the hysteresis), so a state farther than that from all of its regions is one it had no node
    message for: a compromised or misconfigured server speaking of another's vehicles. The reach
    leaves the fused position hundreds of metres from the fix that chose the region (defaults)."""
    reach = cfg.margin_m + cfg.hysteresis_m
    try:
        near = tiles_around(np.asarray(ecef, dtype=float), reach, cfg.size_m)
    except ValueError:  # off the grid (|lat| > 85 deg): no fleet's region
        return False
    return any(shard_of(str(k), cfg.shards) in shards for k in near)
