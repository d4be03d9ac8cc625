"""`FleetEpochs` (the admission's incremental fleet epoch) answers exactly as the rebuild-from-every-
vehicle rule it replaced, whatever the order of updates, expiries and clock values; so does the
fleet's start (the median of the active vehicles' first epochs)."""

from __future__ import annotations

import random

import pytest

from coplane.fusion_server.fleet_epoch import FleetEpochs
from coplane.gtime import GpsTime

LIM = 5.0


def _brute(heard: dict[str, tuple[GpsTime, float]], now: float, exclude: str | None, upper: bool):
    lat = sorted(t for v, (t, s) in heard.items() if now - s <= LIM and v != exclude)
    if not lat:
        return None, 0
    return (lat[len(lat) // 2] if upper else lat[(len(lat) - 1) // 2]), len(lat)


@pytest.mark.parametrize("seed", range(5))
def test_matches_the_rebuild_rule(seed: int) -> None:
    rng = random.Random(seed)
    fe = FleetEpochs(LIM)
    heard: dict[str, tuple[GpsTime, float]] = {}
    firsts: dict[str, GpsTime] = {}
    now = 0.0
    base = GpsTime(2300, 100.0)
    for _ in range(3000):
        op = rng.random()
        vid = f"v{rng.randrange(12)}"
        if op < 0.5:
            now += rng.choice([0.0, 0.1, 0.5, 2.0])
            t = base + float(rng.randrange(8))
            heard[vid] = (t, now)
            first = firsts[vid] = min(t, firsts.get(vid, t))
            fe.update(vid, t, now, first)
        elif op < 0.6:
            heard.pop(vid, None)
            firsts.pop(vid, None)
            fe.update(vid, None, None)
        elif op < 0.65:
            now = max(0.0, now - rng.choice([1.0, 6.0]))  # a test's clock may go back
        else:
            now += rng.choice([0.0, 1.0, 3.0])
        exclude = vid if rng.random() < 0.5 else None
        upper = rng.random() < 0.5
        med, _ = _brute(heard, now, exclude, upper)
        assert fe.median(now, exclude=exclude, upper=upper) == med
        assert fe.count(now) == _brute(heard, now, None, False)[1]
        assert fe.active(now) == {v: t for v, (t, s) in heard.items() if now - s <= LIM}
        # the fleet's start: the lower median of the active vehicles' first epochs
        started = sorted(firsts[v] for v, (_, s) in heard.items() if now - s <= LIM)
        assert fe.first_median(now) == (started[(len(started) - 1) // 2] if started else None)
