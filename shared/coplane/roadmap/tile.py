"""One tile's road plane in information form, and the rule that adds a pass to it (docs/roadmap.md).

Local frame of a tile: East-North-Up about the tile centre at ellipsoidal height `h0_m` (set from
the first evidence and kept). Parameters theta = (a, b, c): the road's ellipsoidal height at local
(e, n) is h0 + a + b e + c n (b the grade east, c the grade north). The tile keeps only evidence,
info theta = eta, so passes add, old evidence decays by a scalar, and the slope prior is added only
when solving: it is a belief about roads, not evidence, and must not decay.

A pass is one vehicle's samples in one tile, time-contiguous. Its errors count as ONE error: a
vehicle's consecutive positions share their multipath and NLOS error over seconds, so twenty
samples of one pass are worth one sample of the offset, not twenty. With passes of equal sigma
the offset sigma then falls as 1/sqrt(passes).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from coplane.geo import geodetic_to_ecef
from coplane.roadmap.config import RoadMapConfig
from coplane.roadmap.grid import TileKey, tile_centre, tile_frame
from coplane.roadmap.reference import NO_REFERENCE, ZReference
from coplane.typing import Mat, Vec

MAD_TO_SIGMA = 1.4826  # sigma of a normal distribution per unit of median absolute deviation
MIN_REJECT_M = 1.0  # in-pass outlier threshold floor: a grade across the tile is not an outlier


@dataclass(frozen=True, eq=False)
class PassEvidence:
    """One vehicle's samples in one tile: road points in the tile's local frame and their vertical
    1-sigmas. `time_s` is the newest sample (GPS seconds, as `GpsTime.seconds`).

    The up coordinate is relative to the tile's `h0_m`, unless `h_ref_m` is given: then it is
    relative to that ellipsoidal height (the builder uses 0, as it does not know a tile's h0; the
    ENU frames about two heights on the tile centre's normal differ only by that shift). `key` names
    the tile for `RoadMap.apply`."""

    vehicle_id: str
    time_s: float
    points_enu: Vec
    sigmas_up_m: Vec
    key: TileKey | None = None
    h_ref_m: float | None = None


@dataclass(frozen=True, eq=False)
class PassSummary:
    """What a tile remembers of a recent pass: its information (in the tile frame, undecayed), its
    standardized mean residual against the tile when it arrived (nan for the tile's first pass) and
    whether it was added. Kept so that a change can be re-learned from the passes that showed it.
    `z` is the one the change detector tested (corrected by the fleet's `ZReference`)."""

    time_s: float
    vehicle_id: str
    info: Mat
    eta: Vec
    n_points: int
    z: float
    accepted: bool


@dataclass(frozen=True)
class ChangeEvent:
    """The road of a tile moved (CUSUM): heights at the tile centre before and after re-learning."""

    key: TileKey
    time_s: float
    old_height_m: float
    new_height_m: float
    passes_used: int


@dataclass(frozen=True)
class TileUpdate:
    """The outcome of one pass: added or not, its z against the tile, and a change if it made one.
    `residual_m`: the pass's mean height residual against the tile (nan for a tile's first pass),
    which `RoadMap` feeds to the fleet's common reference."""

    accepted: bool
    z: float
    change: ChangeEvent | None = None
    residual_m: float = math.nan


def _zeros3x3() -> Mat:
    return np.zeros((3, 3))


def _zeros3() -> Vec:
    return np.zeros(3)


def _decay(dt_s: float, config: RoadMapConfig) -> float:
    """Weight of evidence `dt_s` older than the newest: 0.5 ** (dt / half_life), 1 for dt <= 0."""
    return 1.0 if dt_s <= 0.0 else 0.5 ** (dt_s / config.half_life_s)


@dataclass(eq=False)
class TilePlane:
    """A tile's road plane as accumulated evidence (info, eta) plus the state of its change detector.

    `cusum_pos_n` / `cusum_neg_n` count the passes since each CUSUM side was last 0: the passes a
    change is re-learned from."""

    key: TileKey
    h0_m: float
    info: Mat = field(default_factory=_zeros3x3)
    eta: Vec = field(default_factory=_zeros3)
    n_passes: int = 0
    n_points: int = 0
    outlier_passes: int = 0
    cusum_pos: float = 0.0
    cusum_neg: float = 0.0
    changes: int = 0
    version: int = 0
    updated_s: float = 0.0
    recent: list[PassSummary] = field(default_factory=list)
    cusum_pos_n: int = 0
    cusum_neg_n: int = 0

    # -- checking ------------------------------------------------------------------------------
    def problem(self, config: RoadMapConfig) -> str | None:
        """What makes this tile unfit to give a plane, as stored or received (a tampered file, a
        bit flip, a forged message), or None. The map file and the bus both check with it, so a
        bad tile is skipped and counted there and never reaches the factor graph."""
        if not _in_grid(self.key, config.tile_size_m):
            return "tile key outside the grid"
        if not (math.isfinite(self.h0_m) and -1000.0 <= self.h0_m <= 10000.0):
            return "height out of range"
        if np.shape(self.info) != (3, 3) or np.shape(self.eta) != (3,):
            return "information of the wrong shape"
        if not (np.isfinite(self.info).all() and np.isfinite(self.eta).all()):
            return "non-finite information"
        if not np.array_equal(self.info, self.info.T):
            return "information matrix not symmetric"
        counts = (self.n_passes, self.n_points, self.outlier_passes, self.changes, self.version)
        if min(*counts, self.cusum_pos_n, self.cusum_neg_n) < 0:
            return "negative count"
        if not math.isfinite(self.updated_s):
            return "time not finite"
        # NaN here would silently switch change detection off; a negative CUSUM cannot happen
        if not all(math.isfinite(x) and x >= 0.0 for x in (self.cusum_pos, self.cusum_neg)):
            return "change detector state invalid"
        # a change re-learns the tile from these, so a bad one would poison the tile later
        if any(_summary_problem(p) for p in self.recent):
            return "invalid recent pass"
        if self.n_passes > 0 or np.any(self.info):
            p = 1.0 / config.slope_prior_sigma**2
            try:
                np.linalg.cholesky(self.info + np.diag([0.0, p, p]))
            except np.linalg.LinAlgError:
                return "information matrix not positive definite"
        return None

    # -- reading -------------------------------------------------------------------------------
    def estimate(self, config: RoadMapConfig) -> tuple[Vec, Mat]:
        """theta = (a, b, c) and its covariance: (info + prior) theta = eta, prior diag(0, 1/s^2, 1/s^2)."""
        if not self.info[0, 0] > 0.0:
            raise ValueError(f"tile {self.key} has no offset information yet")
        p = 1.0 / config.slope_prior_sigma**2
        cov = np.linalg.inv(self.info + np.diag([0.0, p, p]))
        cov = 0.5 * (cov + cov.T)
        return cov @ self.eta, cov

    def height_at(self, e: float, n: float, config: RoadMapConfig) -> tuple[float, float]:
        """Road ellipsoidal height at local (e, n) and its 1-sigma (plane uncertainty + roughness)."""
        theta, cov = self.estimate(config)
        j = np.array([1.0, e, n])
        var = float(j @ cov @ j) + config.roughness_sigma_m**2
        return self.h0_m + float(j @ theta), math.sqrt(max(var, 0.0))

    def local_of_ecef(self, p_ecef: ArrayLike, config: RoadMapConfig) -> Vec:
        """(e, n, u) of an ECEF point in this tile's frame (u relative to h0)."""
        origin, rot = tile_frame(self.key, config.tile_size_m)
        enu = rot @ (np.asarray(p_ecef, dtype=float) - origin)
        enu[2] -= self.h0_m
        return enu

    def sigma_at_ecef(self, p_ecef: ArrayLike, config: RoadMapConfig) -> float:
        """1-sigma of the road height at the horizontal position of an ECEF point."""
        e, n, _ = self.local_of_ecef(p_ecef, config)
        return self.height_at(float(e), float(n), config)[1]

    def plane_ecef(self, config: RoadMapConfig) -> tuple[Vec, float]:
        """(unit upward normal, d_road) in ECEF with n . p + d_road = 0 on the road surface, the
        convention of `coplane.plane.fit` (positive distances are above the road)."""
        theta, _ = self.estimate(config)
        _, rot = tile_frame(self.key, config.tile_size_m)
        n_enu = np.array([-theta[1], -theta[2], 1.0])
        normal = rot.T @ (n_enu / math.sqrt(float(n_enu @ n_enu)))
        lat, lon = tile_centre(self.key, config.tile_size_m)
        point = geodetic_to_ecef(lat, lon, self.h0_m + float(theta[0]))
        return normal, -float(normal @ point)

    def usable(self, config: RoadMapConfig) -> bool:
        """Enough accepted passes to give a vehicle a plane (the sigma test is `RoadMap.plane_at`'s)."""
        return self.n_passes >= config.min_passes

    # -- updating ------------------------------------------------------------------------------
    def add_pass(
        self, pass_: PassEvidence, config: RoadMapConfig, reference: ZReference | None = NO_REFERENCE
    ) -> TileUpdate:
        """Add one pass (docs/roadmap.md, "Update rule"): in-pass outlier removal, the pass's
        information, its z against the tile, CUSUM change detection, then add or reject.

        The outlier test uses the pass's own z; the CUSUM tests it against `reference`, the fleet's
        common residual (`coplane.roadmap.reference`), so that an error every tile shares at once is
        not taken for a change of this one. None: the common residual is not known yet, so the pass
        is not tested for a change at all (it is still added)."""
        e, n, u, w = _kept_points(pass_, self.h0_m, config)
        jac = np.column_stack([np.ones_like(e), e, n])
        info_p = jac.T @ (w[:, None] * jac)
        info_p = 0.5 * (info_p + info_p.T)  # exactly symmetric: stored as 6 numbers, bit-exact
        eta_p = jac.T @ (w * u)
        t = float(pass_.time_s)
        # keep the evidence "as of updated_s" whether or not this pass is added, so that a rejected
        # pass advancing updated_s does not skip the decay of the interval before it
        self._decay_to(t, config)
        z = z_change = rbar = sigma = math.nan
        if self.n_passes > 0:
            theta, cov = self.estimate(config)
            wsum = float(w.sum())
            jbar = (w @ jac) / wsum
            rbar = float(w @ (u - jac @ theta)) / wsum
            sigma = math.sqrt(1.0 / float(info_p[0, 0]) + float(jbar @ cov @ jbar))
            z = rbar / sigma
            z_change = reference.z(rbar, sigma) if reference is not None else math.nan
        summary = PassSummary(t, pass_.vehicle_id, info_p, eta_p, int(e.shape[0]), z_change, True)
        change = self._cusum(z_change, summary, config)
        if change is not None:
            accepted = True
        elif math.isnan(z) or abs(z) <= config.outlier_z:
            accepted = True
            late = _decay(self.updated_s - t, config)  # a pass older than the tile's newest evidence
            self.info = self.info + late * info_p
            self.eta = self.eta + late * eta_p
            self.n_passes += 1
            self.n_points += int(e.shape[0])
        else:
            accepted = False
            self.outlier_passes += 1
            summary = PassSummary(t, pass_.vehicle_id, info_p, eta_p, int(e.shape[0]), z_change, False)
        self.recent = [*self.recent, summary][-config.recent_passes :]
        self.version += 1
        self.updated_s = max(self.updated_s, t) if self.version > 1 else t
        return TileUpdate(accepted, z, change, rbar)

    def _decay_to(self, t: float, config: RoadMapConfig) -> None:
        if self.version > 0 and t > self.updated_s:
            f = _decay(t - self.updated_s, config)
            self.info = self.info * f
            self.eta = self.eta * f

    def _cusum(self, z: float, summary: PassSummary, config: RoadMapConfig) -> ChangeEvent | None:
        """Two-sided CUSUM on the clipped z; past `cusum_h`, re-learn from the passes of the run."""
        if math.isnan(z):
            return None
        zc = min(3.0, max(-3.0, z))
        self.cusum_pos = max(0.0, self.cusum_pos + zc - config.cusum_k)
        self.cusum_neg = max(0.0, self.cusum_neg - zc - config.cusum_k)
        self.cusum_pos_n = self.cusum_pos_n + 1 if self.cusum_pos > 0.0 else 0
        self.cusum_neg_n = self.cusum_neg_n + 1 if self.cusum_neg > 0.0 else 0
        if self.cusum_pos > config.cusum_h:
            run = self.cusum_pos_n
        elif self.cusum_neg > config.cusum_h:
            run = self.cusum_neg_n
        else:
            return None
        earlier = self.recent[len(self.recent) - min(run - 1, len(self.recent)) :] if run > 1 else []
        passes = _after_change_point([*earlier, summary])
        old_height = self.h0_m + float(self.estimate(config)[0][0])
        self._relearn(passes, config)
        new_height = self.h0_m + float(self.estimate(config)[0][0])
        self.cusum_pos = self.cusum_neg = 0.0
        self.cusum_pos_n = self.cusum_neg_n = 0
        self.changes += 1
        return ChangeEvent(self.key, summary.time_s, old_height, new_height, len(passes))

    def _relearn(self, passes: list[PassSummary], config: RoadMapConfig) -> None:
        """Replace the evidence by these passes, each decayed to the newest of them and the tile."""
        now = max([self.updated_s, *(p.time_s for p in passes)])
        info, eta = np.zeros((3, 3)), np.zeros(3)
        for p in passes:
            f = _decay(now - p.time_s, config)
            info = info + f * p.info
            eta = eta + f * p.eta
        self.info, self.eta = info, eta
        self.n_passes = len(passes)
        self.n_points = sum(p.n_points for p in passes)


def _in_grid(key: TileKey, size_m: float) -> bool:
    """Whether a key names a tile of the grid (|lat| <= 85 deg, longitude in [-180, 180) deg):
    anything else cannot come from `tile_of_geodetic` and has no frame or outline."""
    try:
        _, lon = tile_centre(key, size_m)
    except (ValueError, OverflowError):
        return False
    return -math.pi <= lon < math.pi


def _summary_problem(p: PassSummary) -> bool:
    """Whether a stored pass summary is unfit to re-learn from: its information must be finite,
    symmetric, of non-negative diagonal (a pass's information is positive semi-definite)."""
    info, eta = np.asarray(p.info), np.asarray(p.eta)
    if info.shape != (3, 3) or eta.shape != (3,):
        return True
    if not (np.isfinite(info).all() and np.isfinite(eta).all() and np.array_equal(info, info.T)):
        return True
    if (np.diag(info) < 0.0).any() or p.n_points < 0 or not math.isfinite(p.time_s):
        return True
    return math.isinf(p.z)  # nan: the tile's first pass


def _after_change_point(run: list[PassSummary]) -> list[PassSummary]:
    """The passes of a CUSUM run from its most likely change point on.

    The run starts where the CUSUM last left 0, which is often a pass or two before the road
    changed (noise had lifted it). For a shift of unknown size the maximum-likelihood change point
    maximises (sum of z after it)^2 / (their count); z clipped to +-3 as in the CUSUM, so one wild
    pass cannot claim the change alone. At least two passes are kept: with the defaults the whole
    run always scores above any single pass (4 h k > 9), and a change is never learnt from one."""
    zc = [min(3.0, max(-3.0, p.z)) if math.isfinite(p.z) else 0.0 for p in run]
    best, best_score = 0, -math.inf
    for s in range(max(1, len(run) - 1)):
        tail = zc[s:]
        score = sum(tail) ** 2 / len(tail)
        if score > best_score:  # ties: the earlier point, more passes
            best, best_score = s, score
    return run[best:]


def _kept_points(pass_: PassEvidence, h0_m: float, config: RoadMapConfig) -> tuple[Vec, Vec, Vec, Vec]:
    """(e, n, u relative to h0, weight) of the pass's points after in-pass outlier removal.

    As the paper excludes outliers before a fit, a point whose height is further from the pass's
    median than max(3 sigma_MAD, 1 m) is dropped. Weights 1 / (N (sigma^2 + roughness^2)) make the
    pass one error: its offset information is that of one sample, however many points it has."""
    pts = np.asarray(pass_.points_enu, dtype=float)
    sig = np.asarray(pass_.sigmas_up_m, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 3 or pts.shape[0] == 0 or sig.shape != (pts.shape[0],):
        raise ValueError(f"pass of {pass_.vehicle_id}: points (N, 3) and sigmas (N,) with N >= 1 expected")
    if not (np.isfinite(pts).all() and np.isfinite(sig).all() and (sig >= 0.0).all()):
        raise ValueError(f"pass of {pass_.vehicle_id}: non-finite points or negative sigmas")
    if not math.isfinite(pass_.time_s):
        raise ValueError(f"pass of {pass_.vehicle_id}: time is not finite")
    u = pts[:, 2] + ((pass_.h_ref_m - h0_m) if pass_.h_ref_m is not None else 0.0)
    med = float(np.median(u))
    mad = float(np.median(np.abs(u - med)))
    keep = np.abs(u - med) <= max(3.0 * MAD_TO_SIGMA * mad, MIN_REJECT_M)
    var = sig[keep] ** 2 + config.roughness_sigma_m**2
    w = 1.0 / (int(keep.sum()) * var)
    return pts[keep, 0], pts[keep, 1], u[keep], w
