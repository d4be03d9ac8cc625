"""The lockstep pacing's wait for vehicles of other servers' regions (issue 16), without the bus."""

from __future__ import annotations

from coplane.fusion_server.pacing import LINKED_WAIT_S, Pacing
from coplane.gtime import GpsTime

T = GpsTime(2320, 1000.0)


class _NoneOwned:
    """A region role that owns none of the awaited vehicles (they belong to other servers)."""

    def owned_vehicles(self, vehicles: list[str]) -> set[str]:
        return set()


def _pacing(first: float, last: float) -> Pacing:
    p = Pacing()
    p.regions = _NoneOwned()  # type: ignore[assignment]
    p.first_arrival, p.last_arrival = {T: first}, {T: last}
    return p


def test_linked_vehicles_are_awaited_until_the_epoch_stops_coming_in() -> None:
    """One load generator puts a 256-vehicle epoch over about 2 s: a vehicle crossing into this
    server's regions late in that order must still be waited for. Counted from the epoch's first
    message the server gave up on it before its copy came (its vehicle-epoch went unanswered)."""
    p = _pacing(first=0.0, last=1.9)
    assert not p._only_linked_overdue(["u250"], T, now=0.0 + LINKED_WAIT_S + 0.5)
    assert p._only_linked_overdue(["u250"], T, now=1.9 + LINKED_WAIT_S)


def test_a_vehicle_of_this_servers_regions_is_never_overdue_here() -> None:
    p = _pacing(first=0.0, last=0.0)
    p.regions.owned_vehicles = lambda vehicles: set(vehicles)  # type: ignore[union-attr, method-assign]
    assert not p._only_linked_overdue(["u1"], T, now=100.0)
