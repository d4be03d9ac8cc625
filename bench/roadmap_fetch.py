"""What an agent receives of the road map: tiles by area (`MapFetch`) against the whole map.

    .venv/bin/python bench/roadmap_fetch.py [--city-km 10] [--block-m 200] [--vehicles 5]
        [--drive-s 1800] [--changed-per-commit 500] [--start-agents 200] [--seed 3] [--out docs/roadmap.md]

A synthetic city: a grid of roads every `--block-m` over a square of `--city-km`, one tile wide
(20 m tiles), held by one fusion server's map (`LiveRoadMap`, in memory). Each vehicle drives a
random route on the grid at 15 m/s for `--drive-s`, one epoch a second, and asks for its map as an
agent does (`MapFetch`, default radius and refresh), the server answering at once in this process
(`LiveRoadMap.answer`, the code the queryable runs). Every 10 s (the server's commit period) the
fleet's evidence changes `--changed-per-commit` random tiles.

Printed per vehicle-hour: the tiles and bytes an agent received and the most tiles it held, for
the area queries (measured) and for the servers' whole-map stream agents took before (counted:
the whole map at start and every 60 s, and every commit's changed tiles, at the measured bytes per
tile of an answer), and the server's time per answer (this host): the first, whole box of each vehicle
and the later ones (median and 99th percentile); and a fleet's start, `--start-agents` agents
asking one server for their whole boxes in turn (the server keeps each tile's JSON between
answers, `coplane.fusion_server.tile_json`), and the same requests queued at once and answered
in the slices the server's loop gives them (`coplane.fusion_server.map_queries`).
"""

from __future__ import annotations

import argparse
import math
import random
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
from docblock import publish  # bench/ is the script's directory, first on sys.path

from coplane.bus import Answered, KeySpace, Request, decode
from coplane.fusion_server.road_map import LiveRoadMap
from coplane.fusion_server.tile_json import EncodedTiles
from coplane.messages import MapTilesMessage
from coplane.roadmap import RoadMapConfig, TileKey, TilePlane, tile_frame, tile_of_geodetic
from coplane.steps.map_tiles import MapReceiver
from coplane.vehicle_agent.map_fetch import MapFetch

MARK = "roadmap_fetch"
COMMIT_S, SNAPSHOT_S, SPEED_MPS = 10.0, 60.0, 15.0


def _tile(key: TileKey, version: int) -> TilePlane:
    return TilePlane(
        key=key, h0_m=41.5, info=np.diag([40.0, 300.0, 300.0]), eta=np.array([4.0, 0.0, 0.0]),
        n_passes=4, n_points=40, version=version, updated_s=1.4e9,
    )  # fmt: skip


class _Query:
    """Zenoh's query as `BusNode.answer` uses it, kept in this process."""

    def __init__(self) -> None:
        self.replies: list[bytes] = []

    def reply(self, key: str, data: bytes) -> None:
        self.replies.append(data)

    def reply_err(self, data: bytes) -> None:
        raise RuntimeError(data.decode())

    def drop(self) -> None:
        pass


class _QueuedBus:
    """`BusNode.request` as the fusion server takes it: queued, answered between its solves."""

    def __init__(self, server: LiveRoadMap) -> None:
        self.server = server

    def request(self, selector: str, tag: int = 0, timeout_s: float = 5.0) -> None:
        key, params = selector.split("?", 1)
        self.server.enqueue(Request(key, dict(p.split("=", 1) for p in params.split(";")), _Query()), key)


class _Bus:
    """`BusNode.request` answered at once by the server; its answer taken by the agent."""

    def __init__(self, server: LiveRoadMap, rx: MapReceiver) -> None:
        self.server, self.rx = server, rx
        self.fetch: MapFetch | None = None
        self.tiles = self.bytes = 0
        self.answer_s: list[float] = []

    def request(self, selector: str, tag: int = 0, timeout_s: float = 5.0) -> None:
        key, params = selector.split("?", 1)
        query = _Query()
        t0 = time.perf_counter()
        self.server.answer(Request(key, dict(p.split("=", 1) for p in params.split(";")), query), key)
        self.answer_s.append(time.perf_counter() - t0)
        for data in query.replies:
            msg = decode(MapTilesMessage, data)
            self.tiles += len(msg.tiles)
            self.bytes += len(data)
            self.rx.take(msg, "")
        self.pending_end = Answered(key, tag)


def city(km: float, block_m: float, size_m: float) -> list[TileKey]:
    """The road tiles of a grid city near 22.3 N, 114.2 E (rows and columns every block)."""
    o = tile_of_geodetic(math.radians(22.3), math.radians(114.2), size_m)
    n, step = int(km * 1000 / size_m), max(1, int(block_m / size_m))
    keys = {TileKey(o.row + i, o.col + j) for i in range(0, n + 1, step) for j in range(n + 1)}
    keys |= {TileKey(o.row + i, o.col + j) for j in range(0, n + 1, step) for i in range(n + 1)}
    return sorted(keys)


def drive(roads: set[TileKey], start: TileKey, steps: int, rng: random.Random) -> list[TileKey]:
    """A random route on the road grid, one tile per step, turning at random at crossings."""
    moves = [(0, 1), (0, -1), (1, 0), (-1, 0)]
    at, (dr, dc) = start, rng.choice(moves)
    route = [at]
    for _ in range(steps):
        options = [
            (r, c) for r, c in moves if TileKey(at.row + r, at.col + c) in roads and (r, c) != (-dr, -dc)
        ]
        if (dr, dc) not in options or (len(options) > 1 and rng.random() < 0.3):
            dr, dc = rng.choice(options or [(-dr, -dc)])
        at = TileKey(at.row + dr, at.col + dc)
        route.append(at)
    return route


def fleet_start(keys: list[TileKey], starts: list[TileKey], tmp: Path, kept: bool) -> list[float]:
    """A fleet's start: a vehicle at each of `starts` asks one server for its whole box, one after
    another as the server's loop takes them; the time of each answer (s). `kept`: the server keeps
    the tiles' JSON between answers (as it does); else each answer encodes its tiles anew."""
    server = LiveRoadMap(tmp / f"start-{kept}.sqlite", {}, fleet="f1")
    server.map.tiles.update({k: _tile(k, 1) for k in keys})
    server.index.touch(keys)
    times = []
    for at in starts:
        if not kept:
            server.encoded = EncodedTiles()
        bus = _Bus(server, MapReceiver("f1"))
        MapFetch(KeySpace("f1"), bus.rx).follow(bus, tile_frame(at, 20.0)[0], 0.0)  # type: ignore[arg-type]
        times += bus.answer_s
    server.close()
    return times


def queued_start(keys: list[TileKey], starts: list[TileKey], tmp: Path) -> tuple[list[float], int]:
    """The same fleet's start through the server's queue (`map_queries`): every agent's request
    queued at once, then answered in the loop's slices; each slice's time (s) and how many
    queries were answered (the others expired)."""
    server = LiveRoadMap(tmp / "start-queued.sqlite", {}, fleet="f1")
    server.map.tiles.update({k: _tile(k, 1) for k in keys})
    server.index.touch(keys)
    bus = _QueuedBus(server)
    for at in starts:
        MapFetch(KeySpace("f1"), MapReceiver("f1")).follow(bus, tile_frame(at, 20.0)[0], 0.0)  # type: ignore[arg-type]
    slices, answered = [], 0
    while len(server.queries):
        t0 = time.perf_counter()
        answered += server.serve_queries()
        slices.append(time.perf_counter() - t0)
    server.close()
    return slices, answered


def run(args: argparse.Namespace) -> tuple[list[str], dict[str, float]]:
    cfg = RoadMapConfig()
    keys = city(args.city_km, args.block_m, cfg.tile_size_m)
    roads = set(keys)
    rng = random.Random(args.seed)
    area, fetched, held, bytes_per_tile = [], [], [], []
    answer_s: list[float] = []  # the answers after each vehicle's first
    first_s: list[float] = []
    with tempfile.TemporaryDirectory() as tmp:
        for v in range(args.vehicles):
            server = LiveRoadMap(Path(tmp) / f"map{v}.sqlite", {}, fleet="f1")
            server.map.tiles.update({k: _tile(k, 1) for k in keys})
            server.index.touch(keys)
            rx = MapReceiver("f1")
            bus = _Bus(server, rx)
            fetch = MapFetch(KeySpace("f1"), rx)
            route = drive(roads, rng.choice(keys), int(args.drive_s * SPEED_MPS / cfg.tile_size_m), rng)
            peak, changed = 0, 0
            for s in range(int(args.drive_s)):
                if s and s % int(COMMIT_S) == 0:  # the fleet's evidence: a commit's changed tiles
                    moved = rng.sample(keys, args.changed_per_commit)
                    for k in moved:
                        server.map.tiles[k] = _tile(k, server.map.tiles[k].version + 1)
                    server.index.touch(moved)
                    changed += len(moved)
                at = route[min(len(route) - 1, int(s * SPEED_MPS / cfg.tile_size_m))]
                if fetch.follow(bus, tile_frame(at, cfg.tile_size_m)[0], float(s)):  # type: ignore[arg-type]
                    fetch.finish(bus.pending_end, float(s))
                assert at in rx.map.tiles, (v, s, at)  # the tile under the vehicle is always there
                peak = max(peak, len(rx.map.tiles))
            hours = args.drive_s / 3600.0
            area.append((bus.tiles / hours, bus.bytes / hours))
            bytes_per_tile.append(bus.bytes / max(1, bus.tiles))
            snapshots = 1 + math.floor(args.drive_s / SNAPSHOT_S)
            fetched.append((len(keys) * snapshots + changed) / hours)
            held.append(peak)
            first_s.append(bus.answer_s[0])  # the whole box, at the first fix
            answer_s += bus.answer_s[1:]
            server.close()
        starts = [rng.choice(keys) for _ in range(args.start_agents)]
        # the same starts with and without the kept JSON, taking turns so they share the host's drift
        start_s, cold_s = [], []
        for half in (starts[::2], starts[1::2]):
            start_s += fleet_start(keys, half, Path(tmp), kept=True)
            cold_s += fleet_start(keys, half, Path(tmp), kept=False)
        slices, queued_answered = queued_start(keys, starts, Path(tmp))
    bpt = statistics.median(bytes_per_tile)
    whole_tiles = statistics.median(fetched)
    area_tiles = statistics.median(t for t, _ in area)
    area_mb = statistics.median(b for _, b in area) / 1e6
    rows = [
        "| what an agent takes | tiles per vehicle-hour | MB per vehicle-hour | tiles held (most) |",
        "| --- | ---: | ---: | ---: |",
        f"| the tiles around it (area queries, measured) | {area_tiles:,.0f} | {area_mb:.1f} | {statistics.median(held):,.0f} |",
        f"| the whole map (the servers' stream, counted) | {whole_tiles:,.0f} | {whole_tiles * bpt / 1e6:,.1f} | {len(keys):,} |",
    ]
    ms = sorted(1e3 * x for x in answer_s)
    stats = {
        "map_tiles": len(keys),
        "ratio": whole_tiles / area_tiles,
        "answer_ms_median": statistics.median(ms),
        "answer_ms_p99": ms[min(len(ms) - 1, int(0.99 * len(ms)))],
        "answers": len(ms),
        "first_ms_median": 1e3 * statistics.median(first_s),
        "start_agents": len(start_s),
        "start_s_total": sum(start_s),
        "start_ms_median": 1e3 * statistics.median(start_s),
        "cold_s_total": sum(cold_s),
        "cold_ms_median": 1e3 * statistics.median(cold_s),
        "bytes_per_tile": bpt,
        "slices": len(slices),
        "slice_ms_max": 1e3 * max(slices),
        "slices_s_total": sum(slices),
        "queued_answered": queued_answered,
    }
    return rows, stats


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--city-km", type=float, default=10.0)
    ap.add_argument("--block-m", type=float, default=200.0)
    ap.add_argument("--vehicles", type=int, default=5)
    ap.add_argument("--drive-s", type=float, default=1800.0)
    ap.add_argument("--changed-per-commit", type=int, default=500)
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--start-agents", type=int, default=200, help="agents asking at once at a fleet's start")
    ap.add_argument("--out", type=Path, default=None, help="write the table into this doc's block")
    args = ap.parse_args()
    rows, st = run(args)
    head = (
        f"A {args.city_km:g} km city with a road every {args.block_m:g} m: {st['map_tiles']:,} tiles; "
        f"{args.vehicles} vehicles of {args.drive_s:g} s each, {args.changed_per_commit} tiles changed "
        f"every {COMMIT_S:g} s; {st['bytes_per_tile']:.0f} bytes per tile. Area queries: "
        f"{st['ratio']:,.0f}x fewer tiles than the whole map. The server's first answer to each "
        f"vehicle (its whole box): median {st['first_ms_median']:.1f} ms; the {st['answers']} answers "
        f"after it (new strips, refreshes): median {st['answer_ms_median']:.2f} ms, p99 "
        f"{st['answer_ms_p99']:.2f} ms. A fleet's start, {st['start_agents']} agents at random places "
        f"asking one server for their whole boxes: {st['start_s_total']:.2f} s of the server's loop "
        f"in all, median {st['start_ms_median']:.1f} ms per answer, with the tiles' JSON kept between "
        f"answers; {st['cold_s_total']:.2f} s, median {st['cold_ms_median']:.1f} ms, encoding every "
        f"answer anew ({st['cold_s_total'] / st['start_s_total']:.1f}x, same run). The same "
        f"{st['start_agents']} requests through the server's queue (answered between solves, "
        f"`map_queries`): {st['queued_answered']} answered in {st['slices']} slices, "
        f"{st['slices_s_total']:.2f} s in all; the longest slice, the longest the loop went "
        f"without looking at its ready epochs, {st['slice_ms_max']:.1f} ms."
    )
    publish(args.out, MARK, "bench/roadmap_fetch.py --out docs/roadmap.md", head, rows)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
