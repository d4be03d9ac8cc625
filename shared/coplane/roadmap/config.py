"""Parameters of the road-surface map (docs/roadmap.md), each with the reason for its default.

A frozen dataclass like `coplane.plane.PlaneConfig`: variants come from `dataclasses.replace`, and
it is validated on construction because it may come from a file (the map database stores it) or a
command line.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import Any

from coplane.errors import require_finite_positive


@dataclass(frozen=True)
class RoadMapConfig:
    """How the map tiles the road, weighs each pass, rejects outliers and notices changes."""

    tile_size_m: float = 20.0
    """Edge of the square tiles. A tile holds one plane: 20 m is short enough that a road's
    vertical curvature departs little from a plane (a 1000 m crest radius: L^2/(27 R) = 1.5 cm RMS,
    L^2/(8 R) = 5 cm peak to peak over 20 m) and long enough that a vehicle's pass through it spans
    one or two seconds of driving."""

    slope_prior_sigma: float = 0.08
    """1-sigma of a zero-mean prior on the grade and the cross-slope, added at solve time and never
    decayed. A tile seen only from one lane has no information on its cross-slope; the prior keeps
    it from claiming one (8 % covers ordinary grades and cross-falls)."""

    roughness_sigma_m: float = 0.05
    """The road's departure from a plane within a tile plus what the model leaves out. Added to
    every pass's sigma (so many passes cannot make a tile sharper than the road is flat) and to the
    sigma of the road height at a point."""

    max_sigma_up_m: float = 3.0
    """Trust filter: a solution with a larger vertical 1-sigma is not evidence of the road."""

    max_sigma_h_m: float = 3.0
    """Trust filter, horizontal: sqrt of the larger horizontal eigenvalue of the covariance. A
    position metres off sideways puts its height in the wrong tile, or off the road."""

    pass_gap_s: float = 3.0
    """A vehicle's samples in one tile separated by more than this are two passes (a vehicle that
    stopped at a light and left, or came back): their errors are no longer one error."""

    outlier_z: float = 5.0
    """A pass whose mean residual against the tile is beyond this many sigma is not added (it may
    still start a change, below)."""

    cusum_k: float = 0.5
    """CUSUM allowance (in sigma): drift per pass that is not accumulated. 0.5 is the textbook
    choice for detecting a shift of about 1 sigma quickly."""

    cusum_h: float = 5.0
    """CUSUM decision limit (in sigma). With z clipped to +-3 a shift well beyond the pass sigma is
    flagged on the third pass; an isolated outlier adds at most 2.5 and never flags alone."""

    change_reference: bool = True
    """Test each pass for a change against the fleet's common residual (`coplane.roadmap.reference`):
    the median residual of the recent passes on usable tiles is taken off first. False: the pass's
    own z, as before 2026-11-27. On the training seeds of bench/roadmap_acceptance.py (sharpening
    121-126, change 141-144) it removed the 9 false changes the raised-road runs made and added
    none (docs/roadmap.md)."""

    change_reference_window_s: float = 120.0
    """The recent passes of the reference: those up to this many seconds (evidence time) before the
    pass. The fleet's common error (the base station's multipath, the atmosphere's residual) drifts
    by tenths of a metre within a 5-minute drive on the simulated ones; 120 s (about 240 passes of
    4 vehicles) follows it. 120 and 600 s made no difference on the training seeds."""

    change_reference_passes: int = 2000
    """At most this many recent passes are kept for the reference (the newest): bounds memory and
    the cost of its medians in a big fleet."""

    change_reference_min_passes: int = 30
    """Fewer recent passes than this (the start of a drive, a restarted server): no reference, and
    the pass is not tested for a change (it is still added to its tile)."""

    recent_passes: int = 16
    """Per-tile buffer of recent pass summaries: after a change the tile is re-learned from the
    passes that showed it, which must still be at hand."""

    half_life_s: float = 90.0 * 86400.0
    """Old evidence is down-weighted by 0.5 ** (dt / half_life_s) when newer evidence arrives (dt
    in GPS seconds of evidence time), so a slowly settling road is followed. inf: never."""

    min_passes: int = 2
    """A tile gives a vehicle a plane only after this many accepted passes: one pass is one
    vehicle's error, which the map could then feed back to that same error."""

    max_use_sigma_m: float = 1.5
    """... and only where the road height's 1-sigma at the vehicle is at or below this. The graph
    weights a map plane by its sigma, so even a metre-level map plane adds height information to a
    vehicle whose own vertical error is metre-level; beyond 1.5 m it adds little. Chosen on the
    training seeds of bench/roadmap_acceptance.py (build 111, use 112: 0.5 / 0.75 / 1.0 / 1.5 / 3.0
    gave pc-map V 1.01 / 0.80 / 0.56 / 0.54 / 0.54 m against pc's 1.03 m, map planes on 16 / 603 /
    1024 / 1120 / 1125 of 1200 vehicle-epochs); docs/results.md ("Road-surface map") reports other seeds."""

    def __post_init__(self) -> None:
        require_finite_positive(
            self,
            (
                "tile_size_m",
                "slope_prior_sigma",
                "roughness_sigma_m",
                "max_sigma_up_m",
                "max_sigma_h_m",
                "pass_gap_s",
                "outlier_z",
                "cusum_h",
                "max_use_sigma_m",
                "change_reference_window_s",
            ),
            "RoadMapConfig.",
        )
        if not (1.0 <= self.tile_size_m <= 1000.0):
            raise ValueError(f"RoadMapConfig.tile_size_m must be in [1, 1000] m, got {self.tile_size_m!r}")
        if not (math.isfinite(self.cusum_k) and self.cusum_k >= 0.0):
            raise ValueError(f"RoadMapConfig.cusum_k must be >= 0 and finite, got {self.cusum_k!r}")
        if not (self.half_life_s > 0.0):  # inf allowed (no decay), NaN rejected
            raise ValueError(f"RoadMapConfig.half_life_s must be > 0, got {self.half_life_s!r}")
        for name in ("recent_passes", "min_passes", "change_reference_passes", "change_reference_min_passes"):
            value = getattr(self, name)
            if not (isinstance(value, int) and not isinstance(value, bool) and value >= 1):
                raise ValueError(f"RoadMapConfig.{name} must be an integer >= 1, got {value!r}")

        if not isinstance(self.change_reference, bool):
            raise ValueError(
                f"RoadMapConfig.change_reference must be true or false, got {self.change_reference!r}"
            )

    def to_dict(self) -> dict[str, Any]:
        """Plain values, for the map database's `meta` table."""
        return asdict(self)

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> RoadMapConfig:
        """The inverse of `to_dict`; keys this version does not know are ignored (a newer writer)."""
        known = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in values.items() if k in known})
