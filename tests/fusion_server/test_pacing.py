"""The lockstep pacing's wait for vehicles of other servers' regions (issue 16), without the bus."""

from __future__ import annotations

from coplane.fusion_server.pacing import LINKED_WAIT_S, Pacing
from coplane.gtime import GpsTime

T = GpsTime(2320, 1000.0)


class _NoneOwned:
    """A region role that owns none of the awaited vehicles (they belong to other servers)."""

    def owned_vehicles(self, vehicles: list[str]) -> set[str]:
        return set()


class _NoneSilent:
    def is_silent(self, vid: str) -> bool:
        return False


def _pacing(first: float, last: float) -> Pacing:
    p = Pacing()
    p.regions = _NoneOwned()  # type: ignore[assignment]
    p.admission = _NoneSilent()  # type: ignore[assignment]
    p.latest = {}
    p.first_arrival, p.last_arrival = {T: first}, {T: last}
    return p


def test_linked_vehicles_are_awaited_until_the_epoch_stops_coming_in() -> None:
    """One load generator puts a 256-vehicle epoch over about 2 s: a vehicle crossing into this
    server's regions late in that order must still be waited for. Counted from the epoch's first
    message the server gave up on it before its copy came (its vehicle-epoch went unanswered)."""
    p = _pacing(first=0.0, last=1.9)
    assert not p._only_linked_overdue({"u250"}, T, now=0.0 + LINKED_WAIT_S + 0.5)
    assert p._only_linked_overdue({"u250"}, T, now=1.9 + LINKED_WAIT_S)


def test_a_vehicle_of_this_servers_regions_is_never_overdue_here() -> None:
    p = _pacing(first=0.0, last=0.0)
    p.regions.owned_vehicles = lambda vehicles: set(vehicles)  # type: ignore[union-attr, method-assign]
    assert not p._only_linked_overdue({"u1"}, T, now=100.0)


def test_only_the_vehicles_still_awaited_count() -> None:
    """A vehicle already heard at the epoch (or later) is not awaited: when the only vehicles left
    are other servers' and the epoch stopped coming in, it is solved, whoever else is live here."""
    p = _pacing(first=0.0, last=0.0)
    p.regions.owned_vehicles = lambda vehicles: {v for v in vehicles if v == "mine"}  # type: ignore[union-attr, method-assign]
    p.latest = {"mine": T}
    assert p._only_linked_overdue({"mine", "theirs"}, T, now=LINKED_WAIT_S)
    p.latest = {"mine": GpsTime(2320, 999.0)}
    assert not p._only_linked_overdue({"mine", "theirs"}, T, now=LINKED_WAIT_S)


class _Owns:
    """Owns u1 (answered elsewhere at T for `answered`), not u2."""

    def __init__(self, answered: bool) -> None:
        self.answered = answered

    def surely_awaited(self, vid: str, t: GpsTime) -> bool:
        return vid == "u1" and not self.answered


def test_an_own_vehicle_still_awaited_keeps_the_epoch_without_the_full_set() -> None:
    """While a vehicle of this server's own regions has not spoken at `t`, the epoch is not ready,
    whatever the linked vehicles are: `RegionRole.awaited` (the range links of the window) is not
    rebuilt for that. Once it spoke, or another server answered it, the full check decides."""
    p = _pacing(first=0.0, last=0.0)
    p.live = {"u1", "u2"}
    p.regions = _Owns(answered=False)  # type: ignore[assignment]
    assert p._own_vehicle_waiting(T)
    p.latest = {"u1": T}
    assert not p._own_vehicle_waiting(T)
    p.latest = {}
    p.regions = _Owns(answered=True)  # type: ignore[assignment]
    assert not p._own_vehicle_waiting(T)
