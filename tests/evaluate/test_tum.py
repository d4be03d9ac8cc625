"""TUM trajectory files (`coplane eval --format tum`): the layout evo's `evo_traj tum` reads.

Checked once by hand with evo 1.38.1 (in a separate venv: evo is not a coplane dependency) on a
simulated recording's non-cp run: `evo_traj tum solutions/non-cp/u1.tum solutions/non-cp/u2.tum
--ref truth/u1.tum` lists 60 poses each, `evo_ape tum truth/u1.tum solutions/non-cp/u1.tum`
gives the APE (rmse 1.58 m) without alignment, since both files share the ENU origin.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from coplane.evaluate.solution_files import write_tum, write_tum_file
from coplane.geo import enu_to_ecef, geodetic_to_ecef
from coplane.gtime import GpsTime


@dataclass
class _Run:  # the two MethodRun attributes write_tum uses
    label: str
    positions: dict[str, dict[GpsTime, np.ndarray]] = field(default_factory=dict)


def _read_like_evo(path: Path) -> np.ndarray:
    """evo's read_tum_trajectory_file: space-separated float rows, '#' comments, 8 columns."""
    rows = np.loadtxt(path, comments="#", delimiter=" ", ndmin=2)
    assert rows.shape[1] == 8
    return rows


def test_tum_enu_about_a_shared_origin(tmp_path: Path) -> None:
    origin = geodetic_to_ecef(np.radians(39.98), np.radians(116.31), 50.0)
    t0 = GpsTime(2320, 115200.0)
    enu = {t0 + k: np.array([10.0 * k, -2.0 * k, 0.5]) for k in (2, 0, 1)}  # out of order on purpose
    run = _Run("pc@r20", {"u2": {t: enu_to_ecef(p, origin) for t, p in enu.items()}, "u1": {}})
    paths = write_tum(run, tmp_path, origin)  # type: ignore[arg-type]
    assert [p.relative_to(tmp_path).as_posix() for p in paths] == [
        "solutions/pc@r20/u1.tum",
        "solutions/pc@r20/u2.tum",
    ]
    rows = _read_like_evo(paths[1])
    assert np.all(np.diff(rows[:, 0]) > 0)  # evo wants increasing stamps
    assert rows[0, 0] == t0.seconds  # GPS seconds since 1980-01-06
    np.testing.assert_allclose(rows[:, 1:4], [enu[t0 + k] for k in range(3)], atol=1e-4)
    np.testing.assert_array_equal(rows[:, 4:], [[0, 0, 0, 1]] * 3)  # identity orientation
    assert "origin_ecef_m" in paths[1].read_text()
    assert paths[0].read_text().startswith("# timestamp")  # a vehicle without fixes: header only


def test_tum_ecef_without_origin_skips_non_finite(tmp_path: Path) -> None:
    t = GpsTime(2320, 1.5)
    n = write_tum_file(
        tmp_path / "a.tum", [(t, np.array([-2.1e6, 4.4e6, 4.1e6])), (t + 1, np.full(3, np.nan))]
    )
    rows = _read_like_evo(tmp_path / "a.tum")
    assert n == 1 and rows.shape == (1, 8)
    np.testing.assert_allclose(rows[0, 1:4], [-2.1e6, 4.4e6, 4.1e6])
