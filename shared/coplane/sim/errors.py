"""GNSS error processes of the simulator, each a small seeded state machine vectorised over arrays.

Every error a real single-frequency car receiver sees is here, with the split that matters for
cooperative positioning and DGNSS: what is common to all receivers in a few km (orbit/clock,
ionosphere, troposphere) versus what is private to one antenna (clock, multipath, NLOS, noise).
Numbers and their sources are in the parameter dataclasses and in docs/simulator.md.

All time-correlated processes are first-order Gauss-Markov, x_k = phi x_(k-1) + sqrt(1-phi^2)
sigma w_k with phi = exp(-dt/tau) (Brown & Hwang, "Introduction to Random Signals and Applied
Kalman Filtering", 4th ed., 2012, sec. 2.9): stationary with standard deviation sigma.
"""

from __future__ import annotations

import math
import zlib
from dataclasses import dataclass, field, replace

import numpy as np

from coplane.gnss.atmosphere import BDS_IONO_EARTH_RADIUS_M, BDS_IONO_HEIGHT_M
from coplane.gnss.constants import C, is_bds_geo
from coplane.recording.model import IonoCoefficients, NavData
from coplane.typing import AnyArray

GPS_CHIP_M = C / 1.023e6  # C/A code chip length
BDS_CHIP_M = C / 2.046e6  # B1I chip length


def component_rng(seed: int, component: str, *extra: int) -> np.random.Generator:
    """An independent random stream per named component (stable across runs and Python versions).

    The component name is turned into an integer with CRC-32 (not `hash`, which is salted per
    process), so the same seed always gives the same stream and adding a component never
    shifts the others.
    """
    return np.random.default_rng(np.random.SeedSequence([seed, zlib.crc32(component.encode()), *extra]))


def gm_phi(dt: float, tau: float) -> float:
    return math.exp(-dt / tau) if tau > 0 else 0.0


class GaussMarkov:
    """Unit-variance first-order Gauss-Markov processes of any shape; scale by sigma outside."""

    def __init__(self, shape: tuple[int, ...], tau_s: float, dt_s: float, rng: np.random.Generator) -> None:
        self.phi = gm_phi(dt_s, tau_s)
        self.q = math.sqrt(max(0.0, 1.0 - self.phi * self.phi))
        self.rng = rng
        self.x = rng.standard_normal(shape)

    def step(self) -> AnyArray:
        self.x = self.phi * self.x + self.q * self.rng.standard_normal(self.x.shape)
        return self.x


# --- parameters ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class CommonModeParams:
    """Broadcast orbit + satellite clock error projected on the line of sight (SISRE).

    GPS ~0.6 m, BeiDou ~1 m RMS, BeiDou GEO ~1.5 m (Montenbruck, Steigenberger & Hauschild 2015,
    "Broadcast versus precise ephemerides: a multi-GNSS perspective", GPS Solutions 19(2), and
    later MGEX monitoring). Identical for every receiver within a few km (the rover-base
    difference of an orbit error is |d_orbit| * baseline / range ~ 1e-4), so DGNSS removes it.
    """

    sigma_m: dict[str, float] = field(default_factory=lambda: {"G": 0.6, "C": 1.0})
    bds_geo_sigma_m: float = 1.5
    drift_sigma_m: float = 0.25  # slowly varying part
    drift_tau_s: float = 1800.0


@dataclass(frozen=True)
class IonoParams:
    """True ionosphere = perturbed broadcast Klobuchar; the receiver removes the unperturbed one.

    Klobuchar removes about 50-60 % of the delay RMS (Klobuchar 1987, IEEE TAES 23(3)); a
    global scale error of ~25 % and per-coefficient errors of ~20 % plus per-satellite
    irregularities reproduce a residual of that size in a solar-maximum year (2024).
    """

    scale_sigma: float = 0.25
    scale_limits: tuple[float, float] = (0.5, 1.8)
    coeff_sigma: float = 0.2
    sat_sigma_m: float = 0.6  # vertical, GPS L1
    sat_tau_s: float = 900.0


@dataclass(frozen=True)
class TropoParams:
    """True troposphere = Saastamoinen standard atmosphere scaled by (1 + e) plus a wet residual.

    Standard-atmosphere Saastamoinen errs by a few cm in zenith (RTKLIB assumes 0.3 m slant
    sigma at 90 deg / sin(el)); the residual maps with 1/sin(el), like the model itself.
    """

    scale_sigma: float = 0.02
    wet_residual_sigma_m: float = 0.05
    wet_tau_s: float = 1800.0


@dataclass(frozen=True)
class ClockParams:
    """Receiver clock: bias and drift random walk, whole-millisecond steering jumps.

    TCXO of a mass-market receiver: frequency offset 0.2-2.5 ppm (1 ppm = 1 us/s), frequency
    random walk ~2e-11 s/s/sqrt(s), phase random walk ~1e-10 s/sqrt(s) (Brown & Hwang ch. 9,
    h_-2/h_0 of a TCXO). u-blox receivers keep the bias within 1 ms of its start value by
    jumping whole milliseconds, and tag epochs in receiver time, so tags sit a few ms off the
    whole second (fleet-recording spec). A geodetic base steers its clock to GPS time instead.
    """

    initial_bias_ms: tuple[float, float] = (-5.0, 5.0)
    drift_ppm: tuple[float, float] = (0.2, 2.5)
    drift_rw: float = 2e-11
    bias_rw: float = 1e-10
    jump_ms: float = 1.0
    steered: bool = False
    steered_sigma_s: float = 1e-8
    isb_sigma_m: float = 3.0  # BeiDou-minus-GPS receiver hardware delay


@dataclass(frozen=True)
class MultipathParams:
    """Code multipath of LOS signals: sigma(el) = z + (h - z) exp(-el / el0), Gauss-Markov in time.

    Values follow the elevation models fitted to automotive receivers (e.g. Kuusniemi 2005
    thesis; RTKLIB's a + b/sin(el) has the same shape); in canyons reflections multiply it.
    A static geodetic antenna sees weaker, slower multipath.
    """

    sigma_zenith_m: float = 0.3
    sigma_horizon_m: float = 3.0
    el_scale_deg: float = 12.0
    tau_s: float = 15.0
    section_scale: dict[str, float] = field(
        default_factory=lambda: {"open": 1.0, "medium": 1.6, "deep": 2.4, "underpass": 2.4}
    )
    scale: float = 1.0


@dataclass(frozen=True)
class NlosParams:
    """NLOS reception: extra path from the canyon geometry, reflection loss, slow jitter.

    Reflection loss off concrete/glass facades is 5-15 dB (Strode & Groves 2016, GPS Solutions
    20: "GNSS multipath detection using three-frequency signal-to-noise measurements").
    """

    cn0_loss_db: tuple[float, float] = (6.0, 16.0)
    jitter_frac: float = 0.08
    jitter_tau_s: float = 10.0
    floor_m: float = 0.5  # diffraction/roughness: the extra path never goes below this


@dataclass(frozen=True)
class Cn0Params:
    """C/N0 = zenith - drop * (1 - sin el)^2 + satellite offset + slow noise (dB-Hz).

    A car-roof patch sees ~45-48 dB-Hz at zenith and ~32-35 dB-Hz at 5-10 deg (u-blox M8/F9
    data: the UrbanNav and Nagoya sets in ../shared/data/real show the same spread).
    """

    zenith_dbhz: float = 47.0
    horizon_drop_db: float = 18.0
    sat_sigma_db: float = 1.5
    noise_sigma_db: float = 1.0
    noise_tau_s: float = 2.0
    bds_geo_offset_db: float = -2.0
    track_threshold_dbhz: float = 25.0


@dataclass(frozen=True)
class TrackingParams:
    """Code/Doppler tracking noise and (re)acquisition.

    Code noise is the coherent early-late DLL jitter (Kaplan & Hegarty, "Understanding GPS",
    2nd ed., eq. 5.75): sigma = chip * sqrt(B d / (2 c/n0) * (1 + 2 / (T c/n0 (2 - d)))),
    with carrier-aided bandwidth B, correlator spacing d (chips), integration time T: 0.5 m for
    GPS at 45 dB-Hz, 3 m at 30 dB-Hz; BeiDou B1I has half the chip length. Doppler noise grows
    as 10^((45 - C/N0)/20) from 0.05 Hz at 45 dB-Hz (FLL-assisted PLL).
    """

    dll_bandwidth_hz: float = 1.0
    correlator_spacing_chips: float = 0.2
    integration_s: float = 0.02
    doppler_sigma_hz_at_45: float = 0.05
    elevation_mask_deg: float = 5.0
    reacquire_epochs: int = 2  # a satellite lost (blocked) is reported again after this many epochs


@dataclass(frozen=True)
class ReceiverParams:
    """Everything private to one class of receiver (vehicle or base)."""

    clock: ClockParams = field(default_factory=ClockParams)
    multipath: MultipathParams = field(default_factory=MultipathParams)
    cn0: Cn0Params = field(default_factory=Cn0Params)
    tracking: TrackingParams = field(default_factory=TrackingParams)
    zenith_spread_db: float = 1.5  # antenna/installation differences between receivers


def base_receiver_params() -> ReceiverParams:
    """A geodetic reference station: steered clock, choke-ring-like antenna, long multipath tau."""
    return ReceiverParams(
        clock=ClockParams(steered=True, drift_ppm=(0.0, 0.0), isb_sigma_m=2.0),
        multipath=MultipathParams(sigma_zenith_m=0.1, sigma_horizon_m=1.0, tau_s=300.0),
        cn0=Cn0Params(zenith_dbhz=50.0, horizon_drop_db=14.0, track_threshold_dbhz=22.0),
        tracking=replace(TrackingParams(), dll_bandwidth_hz=0.5, correlator_spacing_chips=0.1),
        zenith_spread_db=0.0,
    )


# --- models -----------------------------------------------------------------------------------


def code_sigma_m(cn0_dbhz: AnyArray, system_is_bds: AnyArray, p: TrackingParams) -> AnyArray:
    """DLL thermal-noise standard deviation (m) from C/N0 (Kaplan & Hegarty eq. 5.75)."""
    cn0 = 10.0 ** (np.asarray(cn0_dbhz, dtype=float) / 10.0)
    d, b, t = p.correlator_spacing_chips, p.dll_bandwidth_hz, p.integration_s
    chips = np.sqrt(b * d / (2.0 * cn0) * (1.0 + 2.0 / (t * cn0 * (2.0 - d))))
    return chips * np.where(system_is_bds, BDS_CHIP_M, GPS_CHIP_M)


def doppler_sigma_hz(cn0_dbhz: AnyArray, p: TrackingParams) -> AnyArray:
    return p.doppler_sigma_hz_at_45 * 10.0 ** ((45.0 - np.asarray(cn0_dbhz, dtype=float)) / 20.0)


def multipath_sigma_m(el: AnyArray, section_scale: AnyArray, p: MultipathParams) -> AnyArray:
    el0 = math.radians(p.el_scale_deg)
    base = p.sigma_zenith_m + (p.sigma_horizon_m - p.sigma_zenith_m) * np.exp(-np.maximum(el, 0.0) / el0)
    return p.scale * base * section_scale


def klobuchar_obliquity(el: AnyArray, is_bds: AnyArray) -> AnyArray:
    """Slant factor of the broadcast models: GPS 1 + 16 (0.53 - E)^3 (E in semicircles); BeiDou
    1 / sqrt(1 - (R cos el / (R + h))^2) (thin shell at 375 km), as in coplane.gnss.atmosphere."""
    e_sc = np.asarray(el, dtype=float) / math.pi
    gps = 1.0 + 16.0 * (0.53 - e_sc) ** 3
    k = BDS_IONO_EARTH_RADIUS_M / (BDS_IONO_EARTH_RADIUS_M + BDS_IONO_HEIGHT_M) * np.cos(el)
    bds = 1.0 / np.sqrt(1.0 - k * k)
    return np.where(is_bds, bds, gps)


def perturbed_iono(nav: NavData, p: IonoParams, rng: np.random.Generator) -> tuple[NavData, float]:
    """A NavData holding only perturbed Klobuchar coefficients, and the global scale factor."""
    out = NavData()
    for key in sorted(nav.iono):
        c = nav.iono[key]
        a = tuple(float(v) * (1.0 + p.coeff_sigma * rng.standard_normal()) for v in c.alpha)
        b = tuple(float(v) * (1.0 + p.coeff_sigma * rng.standard_normal()) for v in c.beta)
        out.iono[key] = IonoCoefficients(alpha=(a[0], a[1], a[2], a[3]), beta=(b[0], b[1], b[2], b[3]))
    scale = float(np.clip(1.0 + p.scale_sigma * rng.standard_normal(), *p.scale_limits))
    return out, scale


class CommonMode:
    """Per-satellite orbit/clock error shared by all receivers (bias + slow Gauss-Markov)."""

    def __init__(self, sats: list[str], p: CommonModeParams, dt_s: float, rng: np.random.Generator) -> None:
        sig = np.array(
            [p.bds_geo_sigma_m if is_bds_geo(s) else p.sigma_m.get(s[0], 1.0) for s in sats], dtype=float
        )
        self.bias = sig * rng.standard_normal(len(sats))
        self.sigma = p.drift_sigma_m
        self.gm = GaussMarkov((len(sats),), p.drift_tau_s, dt_s, rng)

    def step(self) -> AnyArray:
        return self.bias + self.sigma * self.gm.step()


class ReceiverClocks:
    """Bias (s) and drift (s/s) of N receiver clocks over K epochs, computed up front.

    Free-running clocks integrate drift and jump by whole milliseconds toward their start
    value whenever they have wandered `jump_ms` away (u-blox style); steered clocks stay within
    ~10 ns of GPS time.
    """

    def __init__(
        self, params: list[ClockParams], n_epochs: int, dt_s: float, rng: np.random.Generator
    ) -> None:
        n = len(params)
        self.bias = np.zeros((n_epochs, n))
        self.drift = np.zeros((n_epochs, n))
        self.jumps = np.zeros((n_epochs, n))  # whole-ms jump applied at that epoch (s)
        self.isb_m = np.array([p.isb_sigma_m for p in params]) * rng.standard_normal(n)
        b0 = np.array([rng.uniform(*p.initial_bias_ms) * 1e-3 for p in params])
        sign = np.where(rng.uniform(size=n) < 0.5, -1.0, 1.0)
        d = np.array([rng.uniform(*p.drift_ppm) * 1e-6 for p in params]) * sign
        free = np.array([not p.steered for p in params])
        jump = np.array([p.jump_ms * 1e-3 for p in params])
        qd = np.array([p.drift_rw for p in params]) * math.sqrt(dt_s)
        qb = np.array([p.bias_rw for p in params]) * math.sqrt(dt_s)
        steer = np.array([p.steered_sigma_s for p in params])
        wander = np.zeros(n)
        offset = np.zeros(n)  # accumulated jumps
        for k in range(n_epochs):
            if k > 0:
                wander = wander + d * dt_s + qb * rng.standard_normal(n)
                d = d + qd * rng.standard_normal(n)
            # whole-millisecond steering: keep |wander - offset| below one jump
            over = free & (np.abs(wander - offset) >= jump)
            step = np.where(over, np.sign(wander - offset) * jump, 0.0)
            offset = offset + step
            self.jumps[k] = -step
            steered = steer * rng.standard_normal(n)  # steered to GPS time: white, ~10 ns
            self.bias[k] = np.where(free, b0 + wander - offset, steered)
            self.drift[k] = np.where(free, d, 0.0)
