"""The state block the estimator builds for one vehicle epoch (`coplane.fgo.blocks`)."""

from __future__ import annotations

import dataclasses
from typing import Any

import pytest
from support.fgo_synthetic import make_fleet, run

from coplane.fgo import factors
from coplane.methods import get_method


def test_plane_sigma_scale_weighs_the_plane_factor(monkeypatch: pytest.MonkeyPatch) -> None:
    """`plane_sigma_scale` multiplies each plane factor's sigma (the node's own is left as sent);
    1, the default, passes the node's plane through unchanged."""
    fleet = make_fleet(2, 4, seed=3)
    seen: list[float] = []
    build = factors.plane_factor

    def recording(pos_key: int, plane: Any, *a: Any) -> Any:
        seen.append(plane.sigma_m)
        return build(pos_key, plane, *a)

    monkeypatch.setattr(factors, "plane_factor", recording)
    cfg = get_method("pc").fgo
    run(fleet, cfg)
    plain = list(seen)
    seen.clear()
    run(fleet, dataclasses.replace(cfg, plane_sigma_scale=0.5))
    sent = [v.plane.sigma_m for e in fleet.epochs for v in e.vehicles.values() if v.plane is not None]
    assert plain and sorted(plain) == sorted(sent)
    assert sorted(seen) == sorted(0.5 * s for s in sent)
    with pytest.raises(ValueError, match="plane_sigma_scale"):
        dataclasses.replace(cfg, plane_sigma_scale=0.0)
