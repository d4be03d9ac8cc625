"""Every real RINEX file in ../shared/data/real against RTKLIB (pyrtklib) and georinex.

Observation files: same epochs, same G/C satellites with a pseudorange on the selected signal
(GPS C1C, BeiDou B1I), same pseudorange/Doppler/SNR. Navigation files: every GPS and BeiDou
ephemeris field by field against RTKLIB's eph_t. The three fleet recordings open and iterate.
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import pytest
from support.rtklib_rinex_ref import compare_nav_to_rtklib, read_obs_rtklib

from coplane.recording.problems import Problems
from coplane.recording.reader import open_recording
from coplane.recording.rinex_nav import read_nav
from coplane.recording.rinex_obs import PSEUDORANGE_MAX_M, PSEUDORANGE_MIN_M, read_obs

pytestmark = pytest.mark.realdata

OBS_FILES = [
    "urbannav_hk_tst_20200603_static_f9p/2020_06_03_TST_03.obs",
    "matrtklib_nagoya_static_20240624/base.obs",
    "matrtklib_nagoya_static_20240624/rover.obs",
    "rtklib_geonet_0759_3040_20050402/07590920.05o",
    "rtklib_geonet_0759_3040_20050402/30400920.05o",
    "urbannav_hk_medium_urban1_20210517_kinematic_NONAV/UrbanNav-HK-Medium-Urban-1.ublox.f9p.obs",
    "urbannav_hk_medium_urban1_20210517_kinematic_NONAV/UrbanNav-HK-Medium-Urban-1.ublox.m8t.GC.obs",
    "hk_klt_20210610_f9p_rover_hksc_base/20210610.klt1.ublox.f9p.obs",
    "hk_klt_20210610_f9p_rover_hksc_base/hksc1610.obs",
]
NAV_FILES = [
    "urbannav_hk_tst_20200603_static_f9p/hksc155c.20b",
    "urbannav_hk_tst_20200603_static_f9p/hksc155c.20g",
    "urbannav_hk_tst_20200603_static_f9p/hksc155c.20l",
    "urbannav_hk_tst_20200603_static_f9p/hksc155c.20n",
    "urbannav_hk_tst_20200603_static_f9p/hksc155d.20b",
    "urbannav_hk_tst_20200603_static_f9p/hksc155d.20g",
    "urbannav_hk_tst_20200603_static_f9p/hksc155d.20l",
    "urbannav_hk_tst_20200603_static_f9p/hksc155d.20n",
    "matrtklib_nagoya_static_20240624/base.nav",
    "rtklib_geonet_0759_3040_20050402/07590920.05n",
    "rtklib_geonet_0759_3040_20050402/30400920.05n",
    "hk_klt_20210610_f9p_rover_hksc_base/hksc1610.nav",
]
FLEETS = [
    "matrtklib_nagoya_static_20240624",
    "urbannav_hk_tst_20200603_static_f9p",
    "hk_klt_20210610_f9p_rover_hksc_base",
]
RINEX_SUFFIXES = (".obs", ".nav", ".rnx", ".05o", ".05n", ".20b", ".20g", ".20l", ".20n")


def test_the_lists_cover_every_rinex_file(real_data: Path) -> None:
    found = {
        p.relative_to(real_data).as_posix()
        for p in real_data.glob("*/*")
        if p.suffix in RINEX_SUFFIXES and not p.parent.name.startswith("gsdc")
    }
    assert found == set(OBS_FILES) | set(NAV_FILES)


@pytest.mark.parametrize("rel", OBS_FILES)
def test_obs_matches_rtklib(real_data: Path, rel: str) -> None:
    problems = Problems()
    _, epochs = read_obs(real_data / rel, problems)
    assert problems.total == 0, [str(p) for p in problems.items[:5]]
    ref = read_obs_rtklib(real_data / rel)
    assert [e.time for e in epochs] == list(ref)
    n = 0
    for e in epochs:
        want = ref[e.time]
        got = e.by_sat()
        # RTKLIB stores the Septentrio channel number (type X1) as the L1 pseudorange when C1C is
        # blank: such values are not pseudoranges and must be absent from ours.
        rtklib_only = set(want) - set(got)
        assert all(not PSEUDORANGE_MIN_M <= want[s].pseudorange_m <= PSEUDORANGE_MAX_M for s in rtklib_only)
        assert set(got) <= set(want), f"{e.time}: satellites RTKLIB does not have: {set(got) - set(want)}"
        for sat, s in got.items():
            r = want[sat]
            assert s.pseudorange_m == pytest.approx(r.pseudorange_m, abs=1e-6), (e.time, sat)
            # RTKLIB keeps Doppler as float32 and SNR in 0.001 dB-Hz; 0 means absent there
            assert (math.isnan(s.doppler_hz) and r.doppler_hz == 0.0) or s.doppler_hz == pytest.approx(
                r.doppler_hz, rel=1e-6, abs=1e-3
            ), (e.time, sat)
            assert (math.isnan(s.cn0_dbhz) and r.snr_dbhz == 0.0) or s.cn0_dbhz == pytest.approx(
                r.snr_dbhz, abs=1e-3
            ), (e.time, sat)
            n += 1
    assert n > 0


GEORINEX_FILES = {
    "hk_klt_20210610_f9p_rover_hksc_base/20210610.klt1.ublox.f9p.obs": {"G": "C1C", "C": "C2I"},  # 3.03
    "rtklib_geonet_0759_3040_20050402/07590920.05o": {"G": "C1"},  # 2.10 with splice records
}


@pytest.mark.parametrize("rel", list(GEORINEX_FILES))
def test_obs_matches_georinex(real_data: Path, rel: str) -> None:
    """Every pseudorange/Doppler/SNR georinex has on the selected signals, we have (and no more)."""
    import georinex as gr
    import numpy as np

    codes = GEORINEX_FILES[rel]
    _, epochs = read_obs(real_data / rel, Problems())
    meas = [k + c[1:] for c in codes.values() for k in "CDS"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ds = gr.load(real_data / rel, use=set(codes), meas=meas)
    assert ds.sizes["time"] == len(epochs)
    svs = [str(s) for s in ds.sv.values]
    n = 0
    for i, e in enumerate(epochs):
        y, mo, d, h, mi, sec = e.time.to_calendar()
        tag = np.datetime64(f"{y:04d}-{mo:02d}-{d:02d}T{h:02d}:{mi:02d}:{sec:010.7f}")
        # georinex truncates tags (3.03: to 1 us; 2.10: 30.0020000 becomes 30.001); RTKLIB agrees
        # with ours to 1e-7 s in test_obs_matches_rtklib, so only check that it is the same epoch
        assert abs(ds.time.values[i] - tag) <= np.timedelta64(1, "ms")
        got = e.by_sat()
        for j, sv in enumerate(svs):
            code = codes[sv[0]]
            pr = float(ds[code].values[i, j])
            if math.isnan(pr):
                assert sv not in got
                continue
            s = got[sv]
            assert s.pseudorange_m == pytest.approx(pr, abs=1e-6)
            for attr, var in (("doppler_hz", "D" + code[1:]), ("cn0_dbhz", "S" + code[1:])):
                want = float(ds[var].values[i, j]) if var in ds else math.nan
                assert getattr(s, attr) == pytest.approx(want, abs=1e-6, nan_ok=True), (e.time, sv, var)
            n += 1
    assert n == sum(len(e.sats) for e in epochs) > 0


@pytest.mark.parametrize("rel", NAV_FILES)
def test_nav_matches_rtklib(real_data: Path, rel: str) -> None:
    problems = Problems()
    nav = read_nav(real_data / rel, problems)
    assert problems.total == 0, [str(p) for p in problems.items[:5]]
    n = compare_nav_to_rtklib(real_data / rel, nav)
    is_gc = rel.endswith((".nav", ".20n", ".20b", ".05n"))
    assert (n > 0) == is_gc  # GLONASS/Galileo-only files give no G/C ephemerides


@pytest.mark.parametrize("name", FLEETS)
def test_fleet_recording_opens_and_iterates(real_data: Path, name: str) -> None:
    rec = open_recording(real_data / name)
    fes = list(rec.fleet_epochs())
    vids = [v.id for v in rec.manifest.vehicles]
    n_vehicle = {vid: len(rec.vehicle_epochs(vid)) for vid in vids}
    assert len(fes) >= max(n_vehicle.values()) > 0
    assert all(sum(vid in fe.vehicles for fe in fes) == n for vid, n in n_vehicle.items())
    assert [fe.index for fe in fes] == list(range(len(fes)))
    assert all(fe.time == fe.time.round_to(rec.manifest.interval_s) for fe in fes)
    if rec.manifest.base is not None:
        assert sum(fe.base is not None for fe in fes) == len(rec.base_epochs()) > 0
    for v in rec.manifest.vehicles:
        truth = rec.truth_at(v.id)
        assert (len(truth) > 0) == (v.truth is not None)
    assert rec.nav.satellites
    # these files are clean: any problem here is a reader regression (or a data change to explain)
    assert rec.problems.total == 0, [str(p) for p in rec.problems.items[:10]]
