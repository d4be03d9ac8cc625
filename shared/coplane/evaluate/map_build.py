"""A method's solved positions as evidence for the road-surface map (`coplane map build`).

The map learns from fused positions, weighted by their covariances (docs/roadmap.md). This module
turns one `MethodRun` into the builder's samples, in time order, and applies them to a map; the
trust filter and the grouping into passes live in `coplane.roadmap.builder`. A sample whose
solution was constrained by this map's own plane carries the map plane's height and sigma, so that
the builder can take the map's information back out: a map must not learn from itself.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

from coplane.evaluate.runner import MethodRun
from coplane.recording.reader import Recording
from coplane.roadmap import ChangeEvent, MapBuilder, MapSample, RoadMap
from coplane.steps.map_evidence import map_plane_height


@dataclass
class MapExtension:
    """What one recording added to a map."""

    recording: str
    method: str
    samples: int = 0
    passes: int = 0
    skipped: Counter[str] = field(default_factory=Counter)
    changes: list[ChangeEvent] = field(default_factory=list)
    tiles_touched: int = 0


def run_samples(run: MethodRun, rec: Recording) -> list[MapSample]:
    """Every solved vehicle-epoch of `run` as a map sample, ordered by (time, vehicle)."""
    heights = {v.id: v.antenna_height_m for v in rec.manifest.vehicles}
    out: list[MapSample] = []
    for vid, by_t in run.positions.items():
        covs = run.covariances.get(vid, {})
        planes = run.planes.get(vid, {})
        used = run.plane_used.get(vid, {})
        fix = run.gnss_fix.get(vid, {})
        for t, p in by_t.items():
            mapped = map_plane_height(planes.get(t), used.get(t, False), p)
            out.append(
                MapSample(
                    vehicle_id=vid,
                    time_s=t.seconds,
                    position_ecef_m=p,
                    covariance_m2=covs.get(t),
                    antenna_height_m=heights[vid],
                    has_gnss_fix=fix.get(t, True),
                    map_plane_height_m=None if mapped is None else mapped[0],
                    map_plane_sigma_m=None if mapped is None else mapped[1],
                )
            )
    out.sort(key=lambda s: (s.time_s, s.vehicle_id))
    return out


def extend_map(road_map: RoadMap, run: MethodRun, rec: Recording) -> MapExtension:
    """Apply one run's solutions to `road_map` (in place); what was added and what changed."""
    builder = MapBuilder(road_map.config)
    samples = run_samples(run, rec)
    fresh = [s for s in samples if not road_map.is_mapped(s.vehicle_id, s.time_s)]
    for s in fresh:
        builder.add(s)
    passes = builder.flush()
    changes = road_map.apply(passes)
    ext = MapExtension(rec.manifest.name, run.label, samples=len(samples), passes=len(passes))
    ext.skipped.update(builder.skipped)
    if len(fresh) < len(samples):  # this recording's evidence (or part of it) is in the map already
        ext.skipped["already-mapped"] += len(samples) - len(fresh)
    ext.changes = list(changes)
    ext.tiles_touched = len({(p.key if hasattr(p, "key") else None) for p in passes})
    return ext


def plane_sources(run: MethodRun) -> Counter[str]:
    """Epochs by where the plane came from ("map", "fleet", "self", "none": no plane available)."""
    c: Counter[str] = Counter()
    for by_t in run.planes.values():
        for r in by_t.values():
            c[r.source if r.status != "unavailable" and r.source else "none"] += 1
    return c
