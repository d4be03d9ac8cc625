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

import numpy as np

from coplane.evaluate.runner import MethodRun
from coplane.geo import up_vector
from coplane.messages import PlaneReport
from coplane.recording.reader import Recording
from coplane.roadmap import ChangeEvent, MapBuilder, MapSample, RoadMap
from coplane.typing import AnyArray as Vec


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


def map_plane_height(report: PlaneReport | None, used: bool, position: Vec) -> tuple[float, float] | None:
    """(antenna ellipsoidal height the map's plane implies at `position`, its sigma), or None.

    Only for an epoch whose solution used a plane from the map: its height then leans on the map.
    The plane's signed distance n.p + d_antenna is along its normal; divided by n.up it is the
    vertical offset of the antenna from where the plane puts it.
    """
    if not used or report is None or report.source != "map":
        return None
    if report.normal is None or report.d_antenna_m is None or report.sigma_m is None:
        return None
    n = np.asarray(report.normal, dtype=float)
    cos_tilt = float(n @ up_vector(position))
    if cos_tilt <= 0.5:  # not a road plane; the fusion server's admission rejects these anyway
        return None
    from coplane.geo import ecef_to_geodetic

    h_fused = float(ecef_to_geodetic(position)[2])
    dist = float(n @ position + report.d_antenna_m)
    return h_fused - dist / cos_tilt, float(report.sigma_m) / cos_tilt


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
    for s in samples:
        builder.add(s)
    passes = builder.flush()
    changes = road_map.apply(passes)
    ext = MapExtension(rec.manifest.name, run.label, samples=len(samples), passes=len(passes))
    ext.skipped.update(builder.skipped)
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
