"""The plane step's settings reach only the methods that use planes.

docs/fgo.md relies on it when a table's `non-cp` rows move between two runs that differ in the
plane sigma (PlaneConfig.sigma_model): that cannot come from the planes.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from coplane.evaluate.runner import run_method
from coplane.plane.config import PlaneConfig
from coplane.recording.reader import Recording, open_recording
from coplane.sim.generate import run_simulation
from coplane.sim.write import write_recording


def _positions(rec: Recording, method: str, model: str) -> dict:
    return run_method(rec, method, plane_config=PlaneConfig(sigma_model=model), jobs=1).positions  # type: ignore[arg-type]


def test_the_plane_sigma_moves_pc_and_not_non_cp(tmp_path: Path) -> None:
    rec = open_recording(write_recording(run_simulation("urban-loop", 4, 60.0, 5), tmp_path / "r"))
    a, b = (_positions(rec, "non-cp", m) for m in ("offset", "covariance"))
    assert a.keys() == b.keys()
    for vid in a:
        assert a[vid].keys() == b[vid].keys()
        assert all(np.array_equal(a[vid][t], b[vid][t]) for t in a[vid]), vid
    c, d = (_positions(rec, "pc", m) for m in ("offset", "covariance"))
    assert any(not np.array_equal(c[v][t], d[v][t]) for v in c for t in c[v] if t in d[v])
