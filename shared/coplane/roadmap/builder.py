"""From fused solutions to passes: the trust filter, de-mapping and grouping (docs/roadmap.md).

A `MapSample` is one vehicle's fused antenna position at one epoch with its covariance. The
builder keeps only trustworthy samples, projects each to the road (eq. 1 of the paper, as the
plane history does), and groups each vehicle's consecutive samples in one tile into a pass: the
unit whose errors the map treats as one error.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from coplane.geo import ecef_to_geodetic, enu_rotation, up_vector
from coplane.plane.history import project_to_road
from coplane.roadmap.config import RoadMapConfig
from coplane.roadmap.grid import TileKey, tile_frame, tile_of_ecef
from coplane.roadmap.tile import PassEvidence
from coplane.typing import Mat, Vec


@dataclass(frozen=True, eq=False)
class MapSample:
    """One fused antenna position as map evidence.

    `flagged` is set by callers for solutions they distrust (fault exclusion fired, the plane was
    inconsistent). `map_plane_height_m` / `map_plane_sigma_m`: when the solution was itself
    constrained by this map's plane, the antenna ellipsoidal height that plane implied and its
    sigma, so the builder can take the map's information back out."""

    vehicle_id: str
    time_s: float
    position_ecef_m: ArrayLike
    covariance_m2: ArrayLike | None
    antenna_height_m: float
    has_gnss_fix: bool = True
    flagged: bool = False
    map_plane_sigma_m: float | None = None
    map_plane_height_m: float | None = None


@dataclass
class _OpenPass:
    key: TileKey
    first_s: float
    last_s: float
    rows: list[tuple[float, float, float, float]] = field(default_factory=list)  # e, n, u, sigma


def _pass_order(p: PassEvidence) -> tuple[float, str, TileKey]:
    assert p.key is not None
    return (p.time_s, p.vehicle_id, p.key)


class MapBuilder:
    """Turns a stream of samples (any vehicles, each vehicle's in time order) into passes.

    A pass ends when the vehicle's next sample is in another tile, after a gap over `pass_gap_s`,
    or when no sample of that vehicle came for `pass_gap_s` of the stream's newest time. Passes are
    returned in (time, vehicle, tile) order, so the map they build does not depend on how the
    fleet's samples were interleaved."""

    def __init__(self, config: RoadMapConfig | None = None) -> None:
        self.config = config or RoadMapConfig()
        self.skipped: dict[str, int] = Counter()
        self._open: dict[str, _OpenPass] = {}
        self._ready: list[PassEvidence] = []
        self._newest_s = -math.inf

    def add(self, sample: MapSample) -> None:
        """Filter one sample and put it into its vehicle's current pass (or start a new one)."""
        found = self._evidence(sample)
        if isinstance(found, str):
            self.skipped[found] += 1
            return
        road, sigma_up = found
        key = tile_of_ecef(road, self.config.tile_size_m)
        origin, rot = tile_frame(key, self.config.tile_size_m)
        e, n, u = (float(v) for v in rot @ (road - origin))
        t = float(sample.time_s)
        vid = sample.vehicle_id
        cur = self._open.get(vid)
        if cur is not None and (cur.key != key or not (0.0 <= t - cur.last_s <= self.config.pass_gap_s)):
            self._close(vid)
            cur = None
        if cur is None:
            cur = self._open[vid] = _OpenPass(key, t, t)
        cur.rows.append((e, n, u, sigma_up))
        cur.last_s = t
        self._newest_s = max(self._newest_s, t)

    def passes_ready(self) -> list[PassEvidence]:
        """Passes closed so far (including vehicles silent for over `pass_gap_s`), then forgotten."""
        for vid in sorted(self._open):
            if self._open[vid].last_s < self._newest_s - self.config.pass_gap_s:
                self._close(vid)
        out, self._ready = sorted(self._ready, key=_pass_order), []
        return out

    def flush(self) -> list[PassEvidence]:
        """Close every open pass; all passes not yet returned, in (time, vehicle, tile) order."""
        for vid in sorted(self._open):
            self._close(vid)
        out, self._ready = sorted(self._ready, key=_pass_order), []
        return out

    # -- internals ---------------------------------------------------------------------------
    def _close(self, vid: str) -> None:
        cur = self._open.pop(vid)
        a = np.array(cur.rows, dtype=float)
        self._ready.append(PassEvidence(vid, cur.last_s, a[:, :3], a[:, 3], cur.key, 0.0))

    def _evidence(self, s: MapSample) -> tuple[Vec, float] | str:
        """(road point in ECEF, vertical 1-sigma) of a trustworthy sample, else why it is not."""
        cfg = self.config
        p = np.asarray(s.position_ecef_m, dtype=float)
        if p.shape != (3,) or not np.isfinite(p).all() or not math.isfinite(s.time_s):
            return "not-finite"
        if not (math.isfinite(s.antenna_height_m) and 0.0 <= s.antenna_height_m <= 10.0):
            return "antenna-height"
        if not s.has_gnss_fix:
            return "no-fix"
        if s.flagged:
            return "flagged"
        if s.covariance_m2 is None:
            return "no-covariance"
        cov = np.asarray(s.covariance_m2, dtype=float)
        if cov.shape != (3, 3) or not np.isfinite(cov).all():
            return "no-covariance"
        lat, lon, h_fused = (float(v) for v in ecef_to_geodetic(p))
        rot = enu_rotation(lat, lon)
        c_enu: Mat = rot @ cov @ rot.T
        var_up = float(c_enu[2, 2])
        if not (var_up > 0.0) or math.sqrt(var_up) > cfg.max_sigma_up_m:
            return "sigma-up"
        var_h = float(np.linalg.eigvalsh(0.5 * (c_enu[:2, :2] + c_enu[:2, :2].T))[-1])
        if math.sqrt(max(var_h, 0.0)) > cfg.max_sigma_h_m:
            return "sigma-h"
        if s.map_plane_sigma_m is not None and s.map_plane_height_m is not None:
            demapped = self._demap(h_fused, var_up, s.map_plane_height_m, s.map_plane_sigma_m)
            if demapped is None:
                return "self-mapped"
            h_g, var_up = demapped
            p = p + (h_g - h_fused) * up_vector(p)
        return project_to_road(p, s.antenna_height_m), math.sqrt(var_up)

    def _demap(self, h_f: float, var_f: float, h_p: float, sigma_p: float) -> tuple[float, float] | None:
        """Take the map plane's information out of a fused height ("de-mapping"), along the vertical:
        1/s_g^2 = 1/s_f^2 - 1/s_p^2, h_g = s_g^2 (h_f/s_f^2 - h_p/s_p^2).

        A map must not learn from itself: a solution pulled onto the map's plane, fed back as new
        evidence, would count the map's belief twice and freeze its errors (and hide a change).
        What remains, if anything, is the GNSS's own information. If too little remains (less than
        a sample at `max_sigma_up_m` would carry) the sample is skipped."""
        if not (math.isfinite(h_p) and math.isfinite(sigma_p) and sigma_p > 0.0):
            return None
        info_g = 1.0 / var_f - 1.0 / sigma_p**2
        if info_g <= 1.0 / self.config.max_sigma_up_m**2:
            return None
        var_g = 1.0 / info_g
        return var_g * (h_f / var_f - h_p / sigma_p**2), var_g
