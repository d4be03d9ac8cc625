"""Comparison methods of the paper's Table I that are not the factor graph (docs/methods.md).

Each is a `coplane.estimation.Estimator` (EpochInput in, FleetSolution out), registered by name
in `coplane.methods.METHODS`, so `coplane eval`, the fusion server and the tests run them
exactly like the factor-graph methods (the RTKLIB reference row is not an estimator: it lives
with the evaluator, `coplane.evaluate.rtklib_row`):

- `non-cp-ekf` (`non_cp.NonCpEkf`, on `fleet_filter.FleetFilter`): per-vehicle EKF, pseudorange + Doppler, innovation gating;
- `dd-cp` (`dd_cp.DdCpEkf`): centralised EKF with absolute and inter-vehicle double-differenced
  pseudoranges;
- `gamp-cp` (`gamp_cp.GampCp`): Gaussian GAMP over the fleet graph (GNSS + inter-vehicle ranges);

Equations and settings: docs/methods.md.
"""

from __future__ import annotations

from coplane.baselines.dd_cp import DdCpConfig, DdCpEkf
from coplane.baselines.fleet_filter import EkfConfig
from coplane.baselines.gamp_cp import GampConfig, GampCp
from coplane.baselines.non_cp import NonCpEkf

__all__ = ["DdCpConfig", "DdCpEkf", "EkfConfig", "GampConfig", "GampCp", "NonCpEkf"]
