"""Comparison methods of the paper's Table I that are not the factor graph (design principle 2).

Each is an `coplane.fgo.inputs.Estimator` (EpochInput in, FleetSolution out), registered by name
in `coplane.fgo.methods.METHODS`, so `coplane eval`, the fusion server and the tests run them
exactly like the factor-graph methods:

- `non-cp-ekf` (`ekf.NonCpEkf`): per-vehicle EKF, pseudorange + Doppler, innovation gating;
- `dd-cp` (`dd_cp.DdCpEkf`): centralised EKF with absolute and inter-vehicle double-differenced
  pseudoranges;
- `gamp-cp` (`gamp_cp.GampCp`): Gaussian GAMP over the fleet graph (GNSS + inter-vehicle ranges);
- `rtklib` (`rtklib_row.run_rtklib`): RTKLIB on the recording's RINEX files (optional pyrtklib),
  a reference row of `coplane eval`, not an estimator.

Equations and settings: docs/methods.md.
"""

from __future__ import annotations

from coplane.baselines.dd_cp import DdCpConfig, DdCpEkf
from coplane.baselines.ekf import EkfConfig, NonCpEkf
from coplane.baselines.gamp_cp import GampConfig, GampCp
from coplane.fgo.config import FgoConfig

__all__ = ["DdCpConfig", "DdCpEkf", "EkfConfig", "GampConfig", "GampCp", "NonCpEkf", "gamp_config"]


def gamp_config(fgo: FgoConfig) -> GampConfig:
    """GAMP-CP settings from a method's FgoConfig: ranging on/off and the default UWB sigma."""
    return GampConfig(use_ranging=fgo.use_ranging, range_sigma=fgo.range_sigma)
