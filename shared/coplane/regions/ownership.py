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
