"""Area queries wait in the server and are answered in slices between solves
(`coplane.fusion_server.map_queries`): a fleet's start does not hold the fusion loop."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np

from coplane.bus import Request
from coplane.fusion_server.map_queries import QueryQueue
from coplane.fusion_server.road_map import LiveRoadMap
from coplane.roadmap import TileKey, TilePlane
from coplane.store.roadmap_db import RoadMapDb


class _Clock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


class _Query:
    def __init__(self) -> None:
        self.replies: list[tuple[str, bytes]] = []
        self.errors: list[str] = []
        self.dropped = False

    def reply(self, key: str, data: bytes) -> None:
        self.replies.append((key, data))

    def reply_err(self, data: bytes) -> None:
        self.errors.append(data.decode())

    def drop(self) -> None:
        self.dropped = True


def _request(n: int) -> Request:
    return Request("f/map/tiles/s1", {"box": f"{n},{n},0,0"}, _Query())


class _Loop:
    """A queue and the answers and refusals it gave, each answer costing 20 ms of the clock."""

    def __init__(self, **kw: float) -> None:
        self.clock = _Clock()
        self.answered: list[str] = []
        self.refused: list[tuple[str, str]] = []
        self.q = QueryQueue(Counter(), clock=self.clock, **kw)  # type: ignore[arg-type]

    def answer(self, request: Request, key: str) -> None:
        self.answered.append(request.parameters["box"])
        self.clock.t += 0.02

    def refuse(self, request: Request, key: str, error: str) -> None:
        self.refused.append((request.parameters["box"], error))

    def add(self, n: int) -> None:
        self.q.add(_request(n), "k", self.refuse)

    def serve(self, slice_s: float = 0.05) -> int:
        return self.q.serve(self.answer, self.refuse, slice_s)


def test_answers_oldest_first_in_slices() -> None:
    loop = _Loop()
    for n in range(10):
        loop.add(n)
    assert loop.serve(0.05) == 3  # at 0, 20, 40 ms: the slice is spent
    assert loop.answered == ["0,0,0,0", "1,1,0,0", "2,2,0,0"] and len(loop.q) == 7
    assert loop.serve(0.0) == 1  # at least one per slice: the queue moves
    assert loop.serve(1.0) == 6 and len(loop.q) == 0 and not loop.refused
    assert loop.q.longest_wait_s > 0.0


def test_a_query_its_asker_gave_up_on_is_refused_not_answered() -> None:
    loop = _Loop(max_wait_s=4.0)
    loop.add(0)
    loop.clock.t += 3.0
    loop.add(1)
    loop.clock.t += 1.5  # the first has waited 4.5 s, the second 1.5 s
    assert loop.serve() == 1
    assert loop.answered == ["1,1,0,0"]
    assert loop.refused[0][0] == "0,0,0,0" and "expired: 4.5 s" in loop.refused[0][1]
    assert loop.q.counts["query-expired"] == 1


def test_overflow_is_refused_at_once_and_a_stop_refuses_the_rest() -> None:
    loop = _Loop(max_queued=2)
    for n in range(3):
        loop.add(n)
    assert loop.refused == [("2,2,0,0", "server busy: 2 area queries waiting")]
    assert loop.q.counts["query-overflow"] == 1 and len(loop.q) == 2
    assert loop.q.close(loop.refuse) == 2 and len(loop.q) == 0
    assert [e for _, e in loop.refused[1:]] == ["server stopping", "server stopping"]
    assert loop.q.counts["query-stopped"] == 2 and not loop.answered


def test_the_server_map_answers_queued_queries_and_refuses_them_when_it_closes(tmp_path: Path) -> None:
    path = tmp_path / "map.sqlite"
    tile = TilePlane(
        key=TileKey(2000, 5), h0_m=41.5, info=np.diag([40.0, 300.0, 300.0]), eta=np.array([4.0, 0.0, 0.0]),
        n_passes=4, n_points=40, version=1, updated_s=1.4e9,
    )  # fmt: skip
    with RoadMapDb(path) as db:
        db.write([tile])
    server = LiveRoadMap(path, {}, fleet="f1")
    first, second = (Request("k", {"box": "1990,2010,0,10"}, _Query()) for _ in range(2))
    server.enqueue(first, "f1/map/tiles")
    server.enqueue(second, "f1/map/tiles")
    assert not first.query.replies  # nothing is answered where it arrives
    assert server.serve_queries(slice_s=0.0) == 1  # one slice: the first, then the loop solves
    assert first.query.replies and first.query.dropped and not second.query.replies
    assert server.counts["queries"] == 1 and server.counts["query-tiles"] == 1
    server.close()
    assert second.query.errors == ["server stopping"] and second.query.dropped
    assert server.counts["query-stopped"] == 1
