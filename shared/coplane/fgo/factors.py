"""Factor builders for paper eqs. 21, 24, 27 and 36 on GTSAM's native factors.

Native classes wherever GTSAM has one (C++ evaluation, no Python callback per linearisation):
  - pseudorange (eq. 21): gtsam.PseudorangeFactor(position Point3, clock double in SECONDS)
    or, for a system with an offset from the vehicle's one receiver clock (FgoConfig
    .clock_isb_sigma_m), gtsam.DifferentialPseudorangeFactor(position, clock, offset in METRES)
  - inter-vehicle range (eq. 27): gtsam.RangeFactor3 (Point3-Point3; RangeFactor3D is Pose3-Point3)
  - velocity (eq. 36): gtsam.BetweenFactorPoint3 on the displacement v * dt
  - constant velocity without Doppler (opt-in): a linear gtsam.JacobianFactor on three positions,
    held by a gtsam.LinearContainerFactor (see `acceleration_factor`)
  - receiver clock random walk: gtsam.BetweenFactorDouble (seconds)
  - anchor / fallback priors: gtsam.PriorFactorPoint3, gtsam.PriorFactorDouble
  - plane constraint (eq. 24): gtsam.PriorFactorPoint3 with a rank-1 square-root information
    (GTSAM has no point-on-plane factor; eq. 24 is linear in p, see `plane_factor`)

Sagnac: the PseudorangeFactor of the GTSAM 4.3.0 wheel adds the Earth-rotation (Sagnac) term
omega_e / c * (x_s * y_r - y_s * x_r) itself, i.e. it expects the satellite position in the ECEF
frame at *transmission*. Our inputs (PseudorangeObs, PseudorangeColumns) carry the satellite
already rotated into the ECEF frame at *reception* (`coplane.estimation.contract`), so
`gtsam_satellite_position` rotates it back by omega_e * tau;
the factor then reproduces |p - sat_pos_m| to well under a millimetre (tests/fgo/test_fgo_factors.py).
The correction is detected once at run time, so a GTSAM build without the internal term also works.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence

import gtsam
import numpy as np
from numpy.typing import NDArray

from coplane.estimation.contract import PlaneObs
from coplane.geo import up_vector
from coplane.gnss.constants import OMEGA_E_GPS, C
from coplane.numeric import norm3, row_norms
from coplane.typing import Vec

# ----------------------------------------------------------------------------------------------
# noise models (immutable in GTSAM, so shared instances are safe and save a pybind call each)


@functools.lru_cache(maxsize=8192)
def isotropic(dim: int, sigma: float) -> gtsam.noiseModel.Base:
    return gtsam.noiseModel.Isotropic.Sigma(dim, sigma)


@functools.lru_cache(maxsize=8)
def m_estimator(kernel: str, k: float | None) -> gtsam.noiseModel.mEstimator.Base:
    """The Huber, Cauchy or DCS M-estimator with threshold k (one shared instance per kernel and k)."""
    if k is None or not k > 0:
        raise ValueError(f"robust kernel {kernel!r} needs a positive k, got {k!r}")
    if kernel == "huber":
        return gtsam.noiseModel.mEstimator.Huber.Create(k)
    if kernel == "cauchy":
        return gtsam.noiseModel.mEstimator.Cauchy.Create(k)
    if kernel == "dcs":
        return gtsam.noiseModel.mEstimator.DCS.Create(k)
    raise ValueError(f"unknown robust kernel {kernel!r}")


def with_kernel(base: gtsam.noiseModel.Base, kernel: str | None, k: float | None) -> gtsam.noiseModel.Base:
    """`base` wrapped in the M-estimator `kernel` (huber, cauchy, dcs) when it is set."""
    if kernel is None:
        return base
    return gtsam.noiseModel.Robust.Create(m_estimator(kernel, k), base)


@functools.lru_cache(maxsize=8192)
def robust_isotropic(dim: int, sigma: float, kernel: str | None, k: float | None) -> gtsam.noiseModel.Base:
    """Isotropic Gaussian, wrapped in the M-estimator `kernel` when it is set."""
    return with_kernel(isotropic(dim, sigma), kernel, k)


# ----------------------------------------------------------------------------------------------
# pseudorange (eqs. 18-21)


@functools.cache
def gtsam_applies_sagnac() -> bool:
    """Whether this GTSAM's PseudorangeFactor adds the Sagnac term itself (4.3.0 wheel: yes)."""
    sat = np.array([1.5e7, 1.0e7, 1.8e7])
    rx = np.array([-2.18e6, 4.38e6, 4.08e6])
    f = gtsam.PseudorangeFactor(0, 1, 0.0, sat, 0.0, gtsam.noiseModel.Unit.Create(1))
    extra = float(f.evaluateError(rx, 0.0)[0]) - float(np.linalg.norm(rx - sat))
    sagnac = OMEGA_E_GPS / C * (sat[0] * rx[1] - sat[1] * rx[0])  # about 21 m here
    if abs(extra - sagnac) < 1e-3:
        return True
    if abs(extra) < 1e-3:
        return False
    raise RuntimeError(f"unexpected gtsam.PseudorangeFactor model: extra term {extra} m")


def gtsam_satellite_positions(sat_pos_rx: Vec, receiver: Vec) -> Vec:
    """Satellite positions (n, 3) as gtsam.PseudorangeFactor wants them.

    `sat_pos_rx` is in the ECEF frame at reception (`estimation.contract`: PseudorangeObs,
    PseudorangeColumns). If GTSAM applies the
    Sagnac term itself, rotate back to the frame at transmission by omega_e * tau, tau the signal
    travel time from the approximate receiver position (1 km of position error moves tau by 3 us,
    i.e. the satellite by 6 mm).
    """
    sats = np.asarray(sat_pos_rx, dtype=float).reshape(-1, 3)
    if not gtsam_applies_sagnac():
        return sats
    tau = row_norms(sats - np.asarray(receiver, dtype=float)) / C
    theta = OMEGA_E_GPS * tau
    c, s = np.cos(theta), np.sin(theta)
    # s_rx = R_z(theta) s_tx  =>  s_tx = R_z(theta)^T s_rx, with R_z(theta) = [[c, s, 0],
    # [-s, c, 0], [0, 0, 1]] (the ECEF frame rotated by theta about z), written out per component
    x, y = sats[:, 0], sats[:, 1]
    out = np.empty_like(sats)
    out[:, 0] = c * x - s * y
    out[:, 1] = s * x + c * y
    out[:, 2] = sats[:, 2]
    return out


def pseudorange_factors(
    pos_key: int,
    clock_keys: Sequence[int],
    rho_m: Sequence[float] | Vec,
    sat_pos_rx: Vec,
    sat_clock_s: Sequence[float] | Vec,
    sigma_m: Sequence[float] | Vec,
    receiver_approx: Vec,
    robust: str | None = None,
    robust_k: float | None = None,
    correction_keys: Sequence[int | None] | None = None,
) -> list[gtsam.NonlinearFactor]:
    """All pseudorange factors of one vehicle epoch (one vectorised frame conversion).

    A row with a `correction_keys` entry keys its system's offset from the receiver clock
    (metres, c (dt_clock - dt_system)): GTSAM's `DifferentialPseudorangeFactor`, whose error is
    the `PseudorangeFactor`'s minus that variable (Sagnac the same; tests/fgo/test_motion_models.py),
    so a receiver has one clock and its systems a slowly walking offset each.
    Per-satellite sigmas are all different, so their noise models bypass the caches; the scalars
    go to GTSAM as Python floats (pybind converts numpy scalars several times more slowly).
    """
    sats = gtsam_satellite_positions(sat_pos_rx, receiver_approx)
    corr = correction_keys if correction_keys is not None else [None] * len(sats)
    # a fusion server runs this loop for every satellite of every vehicle epoch: GTSAM's
    # constructors are looked up once, and the kernel (`with_kernel`) wraps each noise model inline
    sigma_model, robust_model = gtsam.noiseModel.Isotropic.Sigma, gtsam.noiseModel.Robust.Create
    kernel = m_estimator(robust, robust_k) if robust is not None else None
    plain, differential = gtsam.PseudorangeFactor, gtsam.DifferentialPseudorangeFactor
    out: list[gtsam.NonlinearFactor] = []
    for ck, dk, r, sat, sc, sg in zip(
        clock_keys, corr, _floats(rho_m), sats, _floats(sat_clock_s), _floats(sigma_m), strict=True
    ):
        noise = sigma_model(1, sg) if kernel is None else robust_model(kernel, sigma_model(1, sg))
        if dk is None:
            out.append(plain(pos_key, ck, r, sat, sc, noise))
        else:
            out.append(differential(pos_key, ck, dk, r, sat, sc, noise))
    return out


def _floats(x: Sequence[float] | Vec) -> list[float]:
    return np.asarray(x, dtype=float).reshape(-1).tolist()


# ----------------------------------------------------------------------------------------------
# plane constraint (eqs. 22-24)


def plane_factor(
    pos_key: int, plane: PlaneObs, robust: str | None = None, robust_k: float | None = None
) -> gtsam.PriorFactorPoint3:
    """Eq. 24: whitened error (n.p + d) / sigma (+ above the plane along the upward normal).

    GTSAM has no point-on-plane factor, but eq. 24 is linear in p: a prior on p0 = -d n (a point
    of the plane) whose square-root information R has the single non-zero row n^T / sigma gives
    R (p - p0) = ((n.p + d) / sigma, 0, 0), all in C++ (a Python CustomFactor would be called back
    at every linearisation). The two zero rows add nothing to the cost, the Hessian or the
    marginals. Eq. 24 writes f = P'^D - p.u_PC with u_PC = -n: the same number. The normal is
    renormalised so the error is a distance whatever the caller's rounding.
    """
    n = np.asarray(plane.normal, dtype=float).reshape(3)
    norm = norm3(n)
    if not (math.isfinite(norm) and norm > 0.5):
        raise ValueError(f"plane normal is not a unit vector: {plane.normal!r}")
    n = n / norm
    d = float(plane.d_m) / norm
    r = np.zeros((3, 3))
    r[0] = n / float(plane.sigma_m)
    # smart=False: always this one model (an axis-aligned normal would become a Diagonal with
    # infinite sigmas, equivalent but a second code path in GTSAM)
    noise = gtsam.noiseModel.Gaussian.SqrtInformation(r, False)
    return gtsam.PriorFactorPoint3(pos_key, -d * n, with_kernel(noise, robust, robust_k))


# ----------------------------------------------------------------------------------------------
# inter-vehicle range (eqs. 25-27), velocity (eqs. 35-36), clock, priors


def range_factor(
    key_a: int,
    key_b: int,
    range_m: float,
    sigma_m: float,
    robust: str | None = None,
    robust_k: float | None = None,
) -> gtsam.RangeFactor3:
    """Eq. 27 with GTSAM's sign: error = |p_a - p_b| - d."""
    return gtsam.RangeFactor3(
        key_a, key_b, float(range_m), robust_isotropic(1, float(sigma_m), robust, robust_k)
    )


def height_link_factor(
    key_a: int,
    key_b: int,
    pos_a: Vec,
    pos_b: Vec,
    antenna_diff_m: float,
    sigma_up_m: float,
    robust: str | None = None,
    robust_k: float | None = None,
) -> gtsam.BetweenFactorPoint3:
    """Two vehicles on one road surface: h_b - h_a = (antenna_b - antenna_a) +- sigma_up_m.

    GTSAM has no height-difference factor between two points, so this is a between factor whose
    horizontal part is nearly free (sigma HEIGHT_LINK_FREE_M, measured from the initial
    positions `pos_a`, `pos_b`) and whose component along local up carries the link."""
    a, b = np.asarray(pos_a, dtype=float), np.asarray(pos_b, dtype=float)
    u = up_vector(a)
    d = b - a
    d = d - float(u @ d) * u + float(antenna_diff_m) * u
    return displacement_factor(key_a, key_b, d, HEIGHT_LINK_FREE_M, a, sigma_up_m, robust, robust_k)


HEIGHT_LINK_FREE_M = 1.0e3  # a height link's horizontal sigma: no horizontal information


def displacement_factor(
    prev_key: int,
    key: int,
    displacement_m: Vec,
    sigma_m: float,
    at: Vec | None = None,
    sigma_up_m: float | None = None,
    robust: str | None = None,
    robust_k: float | None = None,
) -> gtsam.BetweenFactorPoint3:
    """Eq. 36 multiplied by dt: (p_t - p_{t-1}) - v dt with sigma_V dt per axis.

    With `sigma_up_m` (the motion fallback) the component along local up at `at` gets that sigma
    instead: covariance sigma^2 (I - u u^T) + sigma_up^2 u u^T. A `robust` kernel weighs the
    whole 3-D link by its Mahalanobis length.
    """
    d = np.asarray(displacement_m, dtype=float)
    if sigma_up_m is None or at is None or sigma_up_m == sigma_m:
        return gtsam.BetweenFactorPoint3(
            prev_key, key, d, robust_isotropic(3, float(sigma_m), robust, robust_k)
        )
    noise = gtsam.noiseModel.Gaussian.Covariance(_enu_covariance(sigma_m, sigma_up_m, at))
    return gtsam.BetweenFactorPoint3(prev_key, key, d, with_kernel(noise, robust, robust_k))


def _enu_covariance(sigma: float, sigma_up: float, at: Vec) -> NDArray[np.float64]:
    """sigma^2 (I - u u^T) + sigma_up^2 u u^T with u the local up at `at`."""
    u = up_vector(np.asarray(at, dtype=float))
    uu = np.outer(u, u)
    return sigma * sigma * (np.eye(3) - uu) + sigma_up * sigma_up * uu


def acceleration_factor(
    keys: tuple[int, int, int],
    dt0_s: float,
    dt1_s: float,
    sigma_mps: float,
    sigma_up_mps: float,
    at: Vec,
) -> gtsam.LinearContainerFactor:
    """Constant velocity over three states p0, p1, p2 (`keys` in time order):
    (p2 - p1) / dt1 - (p1 - p0) / dt0 = 0, the velocity change, with sigma (m/s) per horizontal
    axis and `sigma_up_mps` along local up at `at`.

    Unlike the motion fallback's link to a frozen last velocity, the velocity here stays a
    function of the window's positions, so pseudoranges that move the earlier states move the
    velocity carried forward (an EKF's velocity state does the same). The relation is linear, so
    a JacobianFactor is exact; GTSAM has no native nonlinear factor on three Point3 and a
    CustomFactor would call back into Python at every linearisation.
    The container's linearisation point is the origin: the factor's b is then the relation's own
    constant (zero), and GTSAM re-centres it at every linearisation.
    """
    # whitened here (the binding takes only diagonal noise): R = L^-1 with L L^T the covariance
    r = np.linalg.inv(np.linalg.cholesky(_enu_covariance(sigma_mps, sigma_up_mps, at)))
    return _second_difference(keys, dt0_s, dt1_s, r, True)


def clock_acceleration_factor(
    keys: tuple[int, int, int], dt0_s: float, dt1_s: float, sigma_mps: float
) -> gtsam.LinearContainerFactor:
    """Constant clock drift over three clocks of one system (seconds, `keys` in time order):
    c (b2 - b1) / dt1 - c (b1 - b0) / dt0 = 0, the drift change, with sigma (m/s). Without a
    Doppler drift this keeps the clock predictable, as a receiver's oscillator is over seconds
    (an EKF's drift state), where a random walk of the clock alone leaves it free every epoch."""
    return _second_difference(keys, dt0_s, dt1_s, np.array([[C / sigma_mps]]), False)


def bias_factor(prev_key: int, key: int, sigma_m: float) -> gtsam.BetweenFactorDouble:
    """A system's offset from the receiver clock (metres) walks by `sigma_m` since its last value."""
    return gtsam.BetweenFactorDouble(prev_key, key, 0.0, isotropic(1, sigma_m))


def linear_container(jf: gtsam.JacobianFactor, is_point: Sequence[bool]) -> gtsam.LinearContainerFactor:
    """A linear factor held at the origin, as this module builds them: `is_point[i]` says whether
    the i-th key is a Point3 (else a double clock)."""
    origin = gtsam.Values()
    for k, point in zip(jf.keys(), is_point, strict=True):
        if point:
            origin.insertPoint3(k, np.zeros(3))  # Point3, as the estimator inserts positions: a
            # VectorXd here would make Values::localCoordinates crash on the type mismatch
        else:
            origin.insert(k, c=0.0)  # a double, as the estimator inserts clocks
    return gtsam.LinearContainerFactor(jf, origin)


def _second_difference(
    keys: tuple[int, int, int],
    dt0_s: float,
    dt1_s: float,
    r: NDArray[np.float64],
    points: bool,
) -> gtsam.LinearContainerFactor:
    """R [(x2 - x1) / dt1 - (x1 - x0) / dt0] = 0 with unit noise (R: the whitening, dim x dim;
    `points`: Point3 keys, else clocks)."""
    a0, a1, a2 = 1.0 / dt0_s, -(1.0 / dt0_s + 1.0 / dt1_s), 1.0 / dt1_s
    unit = gtsam.noiseModel.Isotropic.Sigma(r.shape[0], 1.0)  # Unit: not registered for serialisation
    b = np.zeros(r.shape[0])
    jf = gtsam.JacobianFactor(keys[0], a0 * r, keys[1], a1 * r, keys[2], a2 * r, b, unit)
    return linear_container(jf, (points,) * 3)


def clock_step_sigma_m(dt_s: float, drift_sigma: float, rw_sigma: float) -> float:
    """1-sigma (m) of the receiver-clock change over dt: random walk, plus the drift's sigma x dt."""
    return math.sqrt(rw_sigma * rw_sigma * dt_s + (drift_sigma * dt_s) ** 2)


def clock_factor(prev_key: int, key: int, step_m: float, sigma_m: float) -> gtsam.BetweenFactorDouble:
    """Receiver clock random walk, converted to seconds: (b_t - b_{t-1}) - step / c."""
    return gtsam.BetweenFactorDouble(prev_key, key, step_m / C, isotropic(1, sigma_m / C))


def position_prior(key: int, mean: Vec, cov: NDArray[np.float64]) -> gtsam.PriorFactorPoint3:
    return gtsam.PriorFactorPoint3(
        key, np.asarray(mean, dtype=float), gtsam.noiseModel.Gaussian.Covariance(cov)
    )


def clock_prior(key: int, mean_s: float, sigma_s: float) -> gtsam.PriorFactorDouble:
    return gtsam.PriorFactorDouble(key, float(mean_s), isotropic(1, sigma_s))


def floored_covariance(cov: NDArray[np.float64] | None, floor_sigma: float) -> NDArray[np.float64]:
    """`cov` with its eigenvalues raised to at least floor_sigma^2 (sigma^2 I when unknown)."""
    floor = floor_sigma * floor_sigma
    if cov is None or not np.all(np.isfinite(cov)):
        return np.eye(3) * floor
    sym = 0.5 * (cov + cov.T)
    w, u = np.linalg.eigh(sym)
    return (u * np.maximum(w, floor)) @ u.T
