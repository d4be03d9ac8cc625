"""The estimation layer: the contract every estimator implements and the one input check they share.

`contract` holds what goes in and out (`EpochInput`, `FleetSolution`, the `Estimator` protocol),
`limits` the plausibility bounds every boundary uses, and `validate` turns an untrusted
`EpochInput` into validated arrays (`validate_epoch`). The factor graph (`coplane.fgo`) and the
baselines (`coplane.baselines`) sit above this package and never import each other.
"""

from coplane.estimation.contract import (
    EpochInput,
    Estimator,
    FleetSolution,
    PlaneObs,
    PseudorangeColumns,
    PseudorangeObs,
    RangeObs,
    VehicleEpochInput,
    VehicleEstimate,
    VelocityObs,
)
from coplane.estimation.validate import (
    ValidEpoch,
    ValidPseudoranges,
    ValidRange,
    ValidVehicle,
    validate_epoch,
)

__all__ = [
    "EpochInput",
    "Estimator",
    "FleetSolution",
    "PlaneObs",
    "PseudorangeColumns",
    "PseudorangeObs",
    "RangeObs",
    "ValidEpoch",
    "ValidPseudoranges",
    "ValidRange",
    "ValidVehicle",
    "VehicleEpochInput",
    "VehicleEstimate",
    "VelocityObs",
    "validate_epoch",
]
