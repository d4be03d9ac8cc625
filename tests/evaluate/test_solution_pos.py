"""RTKLIB .pos files of coplane's solutions (`coplane eval --format pos`): RTKLIB's own reader
(`readsol`, through pyrtklib) reads every row back with its position, covariance, quality flag,
satellite count and correction age, so RTKPLOT shows them beside RTKLIB's own solutions."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from coplane.evaluate.runner import MethodRun
from coplane.evaluate.solution_files import method_pos_records, write_method_pos
from coplane.geo import geodetic_to_ecef
from coplane.gtime import GpsTime
from coplane.recording.problems import Problems
from coplane.recording.trajectories import Q_DGPS, Q_DR, Q_SINGLE, read_pos

T0 = GpsTime(2160, 95600.0)
P0 = geodetic_to_ecef(np.radians(22.3), np.radians(114.17), 20.0)
COV = np.array([[1.0, 0.2, -0.1], [0.2, 2.0, 0.3], [-0.1, 0.3, 9.0]])


def _run() -> MethodRun:
    """Four epochs of one vehicle: with the base's corrections, standalone, carried without a
    GNSS fix, and one without a covariance."""
    run = MethodRun("pc", 0.2)
    for k, (fix, age, cov) in enumerate(
        ((True, 1.5, COV), (True, None, COV), (False, None, COV), (True, 2.0, None))
    ):
        t = T0 + k
        run.positions["u1"][t] = P0 + np.array([k, -k, 0.5 * k])
        if cov is not None:
            run.covariances["u1"][t] = cov
        run.gnss_fix["u1"][t] = fix
        run.dgnss_age_s["u1"][t] = age
        run.pseudoranges_used["u1"][t] = 10 + k
    return run


def test_quality_flags_say_what_carried_each_epoch() -> None:
    recs = method_pos_records(_run(), "u1")
    assert [r.quality for r in recs] == [Q_DGPS, Q_SINGLE, Q_DR, Q_DGPS]
    assert [r.n_sats for r in recs] == [10, 11, 12, 13]
    assert [r.age_s for r in recs] == [1.5, 0.0, 0.0, 2.0]
    np.testing.assert_array_equal(recs[3].covariance, np.zeros((3, 3)))  # none reported: zeros, as RTKLIB


def test_rtklib_reads_the_files_back(tmp_path: Path) -> None:
    import pyrtklib  # a dev dependency (pyproject.toml): missing, the test fails

    run = _run()
    [path] = write_method_pos(run, tmp_path, ["rec"])
    assert path.relative_to(tmp_path).as_posix() == "solutions/pc@r20/u1.pos"
    buf = pyrtklib.solbuf_t()
    assert pyrtklib.readsol([str(path)], 1, buf) == 1
    assert buf.n == 4
    truth = method_pos_records(run, "u1")
    for i, want in enumerate(truth):
        sol = buf.data[i]
        assert (sol.stat, sol.ns) == (want.quality, want.n_sats)
        assert sol.age == pytest.approx(want.age_s)
        np.testing.assert_allclose(list(sol.rr)[:3], want.ecef, atol=1e-3)  # 1e-9 deg, 0.1 mm height
        qr = list(sol.qr)  # xx yy zz xy yz zx, float32 in RTKLIB
        cov = want.covariance
        got = [cov[0, 0], cov[1, 1], cov[2, 2], cov[0, 1], cov[1, 2], cov[2, 0]]
        np.testing.assert_allclose(qr, got, atol=2e-3)  # sigmas written to 0.1 mm
    # and coplane's own reader (what `--truth ID=FILE` and the rtklib row use) agrees
    back = read_pos(path, Problems())
    np.testing.assert_allclose([r.ecef for r in back], [r.ecef for r in truth], atol=1e-3)
    assert [r.quality for r in back] == [r.quality for r in truth]
