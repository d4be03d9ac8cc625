"""`SharedHistory` (the load generator's one plane history) gives every vehicle the node messages
its own history would, late joiners and the single-vehicle method included."""

from __future__ import annotations

import pytest

from coplane.evaluate.runner import lockstep_schedule
from coplane.messages import NodeMessage
from coplane.recording.reader import open_recording
from coplane.replay import BaseCorrections, replay_setup
from coplane.sim.generate import bundled_default_path
from coplane.steps import SharedHistory, VehicleStep

N_EPOCHS = 60
LATE = {"u3": 12}  # u3 joins at this epoch: its own history would hold nothing from before


def _run(method: str, shared: bool) -> list[dict[str, NodeMessage]]:
    """Lockstep over the bundled recording's first epochs, ranges left out (planes are the point)."""
    rec = open_recording(bundled_default_path())
    setup = replay_setup(rec.manifest, method)
    ids = [v.id for v in rec.manifest.vehicles]
    steps: dict[str, VehicleStep] = {vid: setup.vehicle_step(rec, vid) for vid in ids}
    feed = SharedHistory(steps.values()) if shared else None
    fusion = setup.fusion_step()
    corrections = BaseCorrections.of(rec, setup.use_dgnss)
    out = []
    for k, (t, live) in enumerate(lockstep_schedule(rec, ids)[:N_EPOCHS]):
        msgs = {
            vid: steps[vid].process(t, ep, corrections.at(t))
            for vid, ep in live.items()
            if k >= LATE.get(vid, 0)
        }
        sol = fusion.solve(t, msgs)
        for step in steps.values():
            if feed is None:
                step.ingest(sol)
        if feed is not None:
            feed.ingest(sol)
        out.append(msgs)
    return out


@pytest.mark.parametrize("method", ["pc", "pc-self"])
def test_shared_history_gives_the_same_node_messages(method: str) -> None:
    own, shared = _run(method, shared=False), _run(method, shared=True)
    n_planes = 0
    for a, b in zip(own, shared, strict=True):
        assert a.keys() == b.keys()
        for vid in a:
            assert a[vid].model_dump() == b[vid].model_dump(), vid
            n_planes += a[vid].plane is not None and a[vid].plane.status != "unavailable"
    if method == "pc":  # (a single vehicle never holds 15 points within 50 m here)
        assert n_planes >= 15  # the comparison covered fitted planes, not only "too few points" (20)
    late = [m["u3"].plane for m in own[LATE["u3"] : LATE["u3"] + 3]]
    assert all(p is not None and p.status == "unavailable" for p in late)  # it starts with nothing


def test_steps_with_different_history_settings_cannot_share() -> None:
    from dataclasses import replace

    from coplane.steps import VehicleStepConfig

    rec = open_recording(bundled_default_path())
    setup = replay_setup(rec.manifest, "pc")
    a = setup.vehicle_step(rec, "u1")
    cfg = VehicleStepConfig(plane=replace(a.plane_config, range_fitting_m=80.0))
    b = VehicleStep(a.fleet, "u2", 1.5, rec.nav, a.method, cfg)
    with pytest.raises(ValueError, match="same history settings"):
        SharedHistory([a, b])
