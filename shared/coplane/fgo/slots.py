"""Which fixed-lag smoother each of an epoch's clusters goes on with, and which it rebuilds.

A slot is one smoother (held by `coplane.fgo.smoother.LocalSmoothers` or a pool under its id)
with the vehicles whose window states it owns. Each epoch the window's clusters
(`Window.partition`) are matched to slots: a cluster that keeps a slot feeds it the new epoch; the
others are rebuilt from the window (`coplane.fgo.solve`). What was marginalised into a smoother
cannot be moved to another: a rebuild replaces it by loose anchors on the window's oldest states,
and converges the window afresh.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from coplane.fgo.config import FgoConfig
from coplane.fgo.window import ClusterView, StateBlock


@dataclass
class Slot:
    """A smoother under `id` that owns `vehicles`' window states."""

    id: int
    vehicles: set[str]
    # split (`FgoConfig.isam2_keep_on_split` off): its remaining vehicles must be rebuilt before
    # they are solved again
    dirty: bool = False


def keepers(
    cfg: FgoConfig,
    slots: Sequence[Slot],
    views: Sequence[ClusterView],
    by_vehicle: Mapping[str, Sequence[StateBlock]],
    step: int,
) -> dict[int, Slot]:
    """The clusters (indices into `views`) that go on with a smoother, and with which.

    A cluster can keep a slot when each of its vehicles is the slot's or seen for the first time
    (its first window state, in `by_vehicle`, is at `step`): a merge, or a vehicle whose earlier
    states are in another smoother or none, is rebuilt. When the slot owns vehicles beyond the cluster
    (it split), every part is rebuilt (the default), or with `isam2_keep_on_split` the part with
    the most of them keeps it, the first such cluster on a tie. The kept smoother still holds the
    departed vehicles' states, tied to its own by the ranges once measured, until they leave its
    lag, as it holds a vehicle that stopped reporting.
    """
    slot_of = {v: slot for slot in slots for v in slot.vehicles}
    best: dict[int, tuple[int, int, Slot]] = {}  # slot id -> (-its vehicles in the cluster, index, slot)
    for i, view in enumerate(views):
        touched = {slot_of[v].id: slot_of[v] for v in view.vehicles if v in slot_of}
        if len(touched) != 1:
            continue
        (slot,) = touched.values()
        members = set(view.vehicles)
        if slot.dirty or not all(v in slot.vehicles or by_vehicle[v][0].step == step for v in view.vehicles):
            continue
        if not (cfg.isam2_keep_on_split or slot.vehicles <= members):
            continue
        score = (-len(slot.vehicles & members), i, slot)
        if slot.id not in best or score[:2] < best[slot.id][:2]:
            best[slot.id] = score
    return {i: slot for _, i, slot in best.values()}
