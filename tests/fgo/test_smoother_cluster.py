"""`SmootherCluster`: what a fixed-lag smoother reports, and how a diverged one is caught.

GTSAM's IncrementalFixedLagSmoother never puts iSAM2's error in its result, so the estimator does
not ask iSAM2 to evaluate it (CPU for nothing) and reports NaN; divergence
is caught on the estimates instead, and the cluster is rebuilt from the window.
"""

from __future__ import annotations

import math
from typing import Any

import gtsam
import numpy as np
import pytest
from support.fgo_synthetic import make_fleet, run

from coplane.fgo import window
from coplane.gtime import GpsTime
from coplane.methods import get_method


def test_isam2_reports_no_graph_error_and_batch_does() -> None:
    fleet = make_fleet(2, 6, seed=3)
    isam2 = run(fleet, get_method("pc", solver="isam2-fixed-lag").fgo)
    batch = run(fleet, get_method("pc", solver="batch-fixed-lag").fgo)
    assert all(math.isnan(s.error_after) for s in isam2)
    assert all(math.isfinite(s.error_after) and s.error_after >= 0.0 for s in batch)


class _Diverged:
    """An iSAM2 smoother stand-in whose estimate has run away to NaN."""

    def __init__(self, real: Any) -> None:
        self.real = real

    def update(self, *args: Any) -> Any:
        return self.real.update(*args)

    def calculateEstimate(self, keys: Any = None) -> gtsam.Values:
        v = gtsam.Values()
        for k in keys:
            v.insert(k, np.full(3, np.nan))
        return v


def test_a_non_finite_estimate_raises() -> None:
    cfg = get_method("pc", solver="isam2-fixed-lag").fgo
    assert cfg is not None
    sm = window.SmootherCluster(cfg, ["a"])
    sm.smoother = _Diverged(sm.smoother)  # type: ignore[assignment]
    g = gtsam.NonlinearFactorGraph()
    g.add(gtsam.PriorFactorPoint3(1, np.zeros(3), gtsam.noiseModel.Isotropic.Sigma(3, 1.0)))
    init = gtsam.Values()
    init.insert(1, np.ones(3))
    blk = window.StateBlock(
        vehicle_id="a",
        step=0,
        time=GpsTime(2100, 0.0),
        pos_key=1,
        clock_keys={},
        init_pos=np.ones(3),
        init_clocks={},
        graph=g,
        counts={},
        links=[],
        n_pseudoranges=0,
        plane_used=False,
        velocity=None,
        clock_drift_mps=None,
        has_fix=True,
    )
    with pytest.raises(RuntimeError, match="non-finite position"):
        sm.update([blk], [], [], init, {1: 0.0}, [], 0, [1])


def test_the_estimator_rebuilds_a_diverged_smoother(monkeypatch: pytest.MonkeyPatch) -> None:
    """One diverged update costs a rebuild from the window, not the vehicles' estimates."""
    fleet = make_fleet(3, 8, seed=4)
    cfg = get_method("pc", solver="isam2-fixed-lag").fgo
    clean = run(fleet, cfg)
    real_update = window.SmootherCluster.update
    calls: list[tuple[int, bool]] = []  # (smoother, raised) per update
    seen: dict[int, int] = {}

    def update(self: window.SmootherCluster, *a: Any, **kw: Any) -> Any:
        sid = seen.setdefault(id(self), len(seen))
        diverge = sid == 0 and sum(1 for s, _ in calls if s == 0) == 2  # the first one's third update
        real = self.smoother
        if diverge:
            self.smoother = _Diverged(real)  # type: ignore[assignment]
        try:
            out = real_update(self, *a, **kw)
        except RuntimeError:
            calls.append((sid, True))
            raise
        finally:
            self.smoother = real
        calls.append((sid, False))
        return out

    monkeypatch.setattr(window.SmootherCluster, "update", update)
    sols = run(fleet, cfg)
    assert calls[2] == (0, True)
    assert calls[3][0] > 0  # the same cluster, solved again by a smoother built from the window
    for a, b in zip(clean, sols, strict=True):
        assert set(a.estimates) == set(b.estimates)
        assert not b.skipped
        for vid, e in b.estimates.items():
            assert np.isfinite(e.position_m).all()
            assert np.linalg.norm(e.position_m - a.estimates[vid].position_m) < 1.0
