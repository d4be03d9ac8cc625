"""Measurement noise models: shape (monotonic in elevation and C/N0) and RTKLIB's varerr."""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import numpy as np
import pytest
from support import rtklib_ref as ref

from coplane.geo import ecef_to_geodetic, enu_rotation
from coplane.gnss.atmosphere import GPS_L1_TO_BDS_B1I, klobuchar_gps_m
from coplane.gnss.ephemeris import geometric_range, satellite_states
from coplane.gnss.weighting import (
    DEFAULT_WEIGHTING,
    WeightingModel,
    doppler_sigma_mps,
    pseudorange_sigma_m,
    rtklib_variance_m2,
    standalone_pseudorange_sigma_m,
)

D = math.radians
ELS = [D(v) for v in np.linspace(5.0, 90.0, 35)]
CN0S = list(np.linspace(15.0, 55.0, 41))


@pytest.mark.parametrize("sigma", [pseudorange_sigma_m, doppler_sigma_mps])
@pytest.mark.parametrize("system", ["G", "C"])
def test_sigma_decreases_with_elevation_and_cn0(sigma, system: str) -> None:  # type: ignore[no-untyped-def]
    for cn0 in (20.0, 35.0, 50.0, math.nan):
        values = [sigma(el, cn0, system) for el in ELS]
        assert all(b < a for a, b in itertools.pairwise(values)), cn0
    for el in (D(7.0), D(30.0), D(90.0)):
        values = [sigma(el, cn0, system) for cn0 in CN0S]
        assert all(b < a for a, b in itertools.pairwise(values)), el


def test_sigma_formula_values() -> None:
    m = DEFAULT_WEIGHTING
    assert pseudorange_sigma_m(math.pi / 2, m.cn0_ref_dbhz, "G") == pytest.approx(math.sqrt(3 * 0.3**2))
    # 30 deg, 35 dB-Hz: 0.09 + 0.09/0.25 + 0.09*10
    assert pseudorange_sigma_m(D(30.0), 35.0, "G") == pytest.approx(math.sqrt(0.09 + 0.36 + 0.9))
    assert doppler_sigma_mps(math.pi / 2, 45.0, "C") == pytest.approx(math.sqrt(3 * 0.05**2))
    # missing C/N0 is treated as the reference value; below the mask the elevation is clamped
    assert pseudorange_sigma_m(D(40.0), math.nan, "G") == pseudorange_sigma_m(D(40.0), 45.0, "G")
    assert pseudorange_sigma_m(D(1.0), 40.0, "G") == pseudorange_sigma_m(D(5.0), 40.0, "G")
    assert pseudorange_sigma_m(-0.1, 40.0, "G") == pseudorange_sigma_m(D(5.0), 40.0, "G")
    assert math.isfinite(pseudorange_sigma_m(0.0, 0.0, "C"))


def test_system_factor_and_custom_model() -> None:
    assert pseudorange_sigma_m(D(45.0), 40.0, "C") == pseudorange_sigma_m(D(45.0), 40.0, "G")
    assert pseudorange_sigma_m(D(45.0), 40.0, "R") == pytest.approx(
        1.5 * pseudorange_sigma_m(D(45.0), 40.0, "G")
    )
    elevation_only = WeightingModel(code_c_m=0.0)
    assert pseudorange_sigma_m(D(45.0), 20.0, "G", elevation_only) == pseudorange_sigma_m(
        D(45.0), 50.0, "G", elevation_only
    )
    bds_worse = WeightingModel(system_factor={"G": 1.0, "C": 2.0})
    assert pseudorange_sigma_m(D(45.0), 40.0, "C", bds_worse) == pytest.approx(
        2.0 * pseudorange_sigma_m(D(45.0), 40.0, "G", bds_worse)
    )


def test_epoch_arrays_give_the_per_satellite_values() -> None:
    """SPP evaluates a whole epoch at once; each entry must be that satellite's scalar value."""
    rng = np.random.default_rng(7)
    n = 40
    el = rng.uniform(-0.1, math.pi / 2, n)
    cn0 = rng.uniform(15.0, 55.0, n)
    cn0[::7] = math.nan
    iono = rng.uniform(0.0, 15.0, n)
    systems = list(rng.choice(["G", "C", "R", "S"], n))
    model = WeightingModel(system_factor={"G": 1.0, "C": 1.7, "R": 1.5})
    vec = {
        "code": pseudorange_sigma_m(el, cn0, systems, model),
        "doppler": doppler_sigma_mps(el, cn0, systems, model),
        "standalone": standalone_pseudorange_sigma_m(el, cn0, systems, iono),
        "rtklib": rtklib_variance_m2(el, systems),
    }
    for i, s in enumerate(systems):
        assert vec["code"][i] == pytest.approx(pseudorange_sigma_m(el[i], cn0[i], s, model), rel=1e-14)
        assert vec["doppler"][i] == pytest.approx(doppler_sigma_mps(el[i], cn0[i], s, model), rel=1e-14)
        assert vec["standalone"][i] == pytest.approx(
            standalone_pseudorange_sigma_m(el[i], cn0[i], s, iono[i]), rel=1e-14
        )
        assert vec["rtklib"][i] == pytest.approx(rtklib_variance_m2(el[i], s), rel=1e-14)
    assert all(isinstance(v, np.ndarray) and v.shape == (n,) for v in vec.values())
    assert isinstance(pseudorange_sigma_m(0.5, 40.0, "G"), float)  # one satellite: a plain float


def test_rtklib_variance_reproduces_pntpos_varerr() -> None:
    """RTKLIB 2.4.3 b34 pntpos.c varerr with prcopt_default err = {100, 0.003, 0.003}:
    var = EFACT^2 * 100^2 * (0.003^2 + 0.003^2 / sin(max(el, 5 deg)))."""
    assert rtklib_variance_m2(math.pi / 2, "G") == pytest.approx(0.18)
    assert rtklib_variance_m2(D(30.0), "G") == pytest.approx(0.09 + 0.09 / 0.5)
    assert rtklib_variance_m2(D(30.0), "C") == rtklib_variance_m2(D(30.0), "G")  # EFACT_GPS used for BDS
    assert rtklib_variance_m2(D(30.0), "R") == pytest.approx(1.5**2 * 0.27)  # EFACT_GLO
    assert rtklib_variance_m2(D(30.0), "S") == pytest.approx(3.0**2 * 0.27)  # EFACT_SBS
    floor = 0.09 + 0.09 / math.sin(D(5.0))
    assert rtklib_variance_m2(D(2.0), "G") == pytest.approx(floor)  # MIN_EL clamp
    assert rtklib_variance_m2(D(5.0), "G") == pytest.approx(1.1226, abs=1e-4)
    assert rtklib_variance_m2(D(30.0), "G", iono_free=True) == pytest.approx(9 * 0.27)
    assert rtklib_variance_m2(D(30.0), "G", err=(100.0, 0.005, 0.002)) == pytest.approx(0.25 + 0.04 / 0.5)


# --- the whole RTKLIB-equivalent variance against RTKLIB's own least squares -----------------


@pytest.mark.realdata
@pytest.mark.parametrize(
    ("folder", "obs_file", "nav_file"),
    [
        ("matrtklib_nagoya_static_20240624", "rover.obs", "base.nav"),
        ("hk_klt_20210610_f9p_rover_hksc_base", "hksc1610.obs", "hksc1610.nav"),
    ],
)
def test_rtklib_variance_reproduces_pntpos_covariance(
    real_data: Path, folder: str, obs_file: str, nav_file: str
) -> None:
    """RTKLIB's SPP covariance is (H' W H)^-1 with W from rescode's variance sum. Rebuilding it
    from our satellite states, Klobuchar, and `rtklib_variance_m2` checks the variance model in
    the RTKLIB binary itself (EFACT for BDS, sin(el) not squared), not just in its source.

    rescode: var = varerr(el) + URA^2 + ERR_CBIAS^2 + vion + (ERR_SAAS / (sin el + 0.1))^2, with
    vion = (ERR_BRDCI * ion_L1)^2 * (f_L1/f)^2 (scaled once, while the delay itself is scaled by
    (f_L1/f)^2 too: for BDS the variance is (0.5 * ion_B1I)^2 / 1.018).
    """
    obs = ref.load_obs(real_data / folder / obs_file)
    rnav = ref.load_nav(real_data / folder / nav_file)
    nav = ref.navdata_from_rtklib(rnav)
    epochs = ref.split_epochs(obs)
    worst = 0.0
    for ep in (epochs[0], epochs[len(epochs) // 2], epochs[-1]):
        sol = ref.pntpos(ep, rnav)
        assert sol.ok, sol.message
        states = satellite_states(nav, ep.time, ref.epoch_pseudoranges(ep))
        lat, lon, _ = ecef_to_geodetic(sol.pos)
        rot = enu_rotation(lat, lon)
        rows, weights = [], []
        for sat in sol.azel:
            st = states[sat]
            _, e = geometric_range(st.pos, sol.pos)
            el = math.asin(float(rot[2] @ e))
            az = math.atan2(float(rot[0] @ e), float(rot[1] @ e)) % (2 * math.pi)
            ion_l1 = klobuchar_gps_m(ep.time, lat, lon, az, el, nav.iono["G"])
            to_b1 = GPS_L1_TO_BDS_B1I if sat[0] == "C" else 1.0
            var = (
                rtklib_variance_m2(el, sat[0])
                + st.variance_m2
                + 0.3**2
                + (0.5 * ion_l1) ** 2 * to_b1
                + (0.3 / (math.sin(el) + 0.1)) ** 2
            )
            rows.append([-e[0], -e[1], -e[2], 1.0, 1.0 if sat[0] == "C" else 0.0])
            weights.append(1.0 / var)
        h = np.array(rows)
        q = np.linalg.inv(h.T @ (np.array(weights)[:, None] * h))[:3, :3]
        worst = max(worst, float(np.max(np.abs(q - sol.cov_pos) / np.abs(sol.cov_pos).max())))
    print(f"\n{folder}: RTKLIB pntpos covariance rebuilt to {worst:.1e} (relative; RTKLIB stores float32)")
    assert worst < 1e-6
