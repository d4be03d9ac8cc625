"""The two pure per-epoch objects every path shares: `VehicleStep` and `FusionStep`.

No I/O and deterministic: `coplane eval` calls them in-process, the vehicle agent and the fusion
server call them over the bus, so the lockstep bus replay equals the in-process run.
"""

from coplane.steps.fusion import FusionStep, FusionStepConfig
from coplane.steps.shared_history import SharedHistory
from coplane.steps.vehicle import VehicleStep, VehicleStepConfig
from coplane.steps.wire import epoch_time, gps_time, plane_report, plane_summary

__all__ = [
    "FusionStep",
    "FusionStepConfig",
    "SharedHistory",
    "VehicleStep",
    "VehicleStepConfig",
    "epoch_time",
    "gps_time",
    "plane_report",
    "plane_summary",
]
