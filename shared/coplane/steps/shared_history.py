"""One plane history for many `VehicleStep`s in one process: the load generator's.

Every agent stores every fleet solution in its own `PositionHistory` (paper eq. 2), so N vehicles
in one process would store each solution N times: O(N^2) work per epoch, which made the load
generator, not the fusion servers, the limit of the scale benchmark (docs/performance-scale.md).
They all receive the same solutions, so one history holds the same points; each step's query
keeps only the points since its first epoch (`since_time_s`), which is what its own history would
have stored. The one difference: a cell trimmed to its newest `max_points_per_cell` points is
trimmed by every vehicle's points together; at 4096 points per 50 m cell that needs a parked
fleet. Real agents keep their own history (one process per vehicle).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import replace

from coplane.messages import SolutionMessage
from coplane.plane.history import PositionHistory
from coplane.steps.vehicle import VehicleStep, store_states
from coplane.steps.wire import gps_time


class SharedHistory:
    """Feeds one `PositionHistory` from the fleet's solutions for every step attached to it."""

    def __init__(self, steps: Iterable[VehicleStep]) -> None:
        self.steps = {s.vehicle_id: s for s in steps}
        # fault exclusion is the plane fit's business, not the history's
        configs = {replace(s.plane_config, fault_exclusion=True) for s in self.steps.values()}
        if len(configs) > 1:
            raise ValueError("steps that share a plane history need the same history settings")
        first = next(iter(self.steps.values()), None)
        self.history = PositionHistory(first.plane_config if first is not None else None)
        self.keeps_points = any(s.method.planes != "none" for s in self.steps.values())
        for s in self.steps.values():
            s.share_history(self.history)

    def ingest(self, solution: SolutionMessage) -> None:
        """Store the solution once; each step that has started notes its own fused position."""
        t = gps_time(solution.epoch)
        states = solution.vehicles
        if states and self.keeps_points:
            store_states(self.history, t, states)
        for v in states:
            step = self.steps.get(v.vehicle_id)
            if step is not None and step.first_epoch is not None and not t < step.first_epoch:
                step.note_fused(t, v.position_ecef_m)
