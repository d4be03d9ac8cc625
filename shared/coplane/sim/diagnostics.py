"""Optional per-measurement record of what the simulator injected, for tests and error budgets.

Not written to the recording: a real receiver does not know these numbers either. See
docs/simulator.md (validation).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from coplane.sim.epoch import EpochResult
from coplane.sim.errors import ReceiverClocks
from coplane.typing import AnyArray

NOT_VISIBLE = -1  # diagnostics state for satellites below the mask or without ephemeris
_DIAG_FIELDS = (
    "el", "cn0", "common_m", "iono_res_m", "tropo_res_m", "multipath_m", "nlos_m", "noise_m", "code_sigma_m",
)  # fmt: skip


@dataclass
class Diagnostics:
    """Per epoch (K), receiver (N = vehicles then base) and satellite (S) injected components.

    state: NOT_VISIBLE / LOS / NLOS / BLOCKED; reported: written to the RINEX file. The error
    components are metres of pseudorange; `iono_res_m` and `tropo_res_m` are what remains after
    the broadcast Klobuchar and standard Saastamoinen models a receiver applies.
    """

    sats: list[str]
    state: AnyArray
    reported: AnyArray
    el: AnyArray
    cn0: AnyArray
    common_m: AnyArray
    iono_res_m: AnyArray
    tropo_res_m: AnyArray
    multipath_m: AnyArray
    nlos_m: AnyArray
    noise_m: AnyArray
    code_sigma_m: AnyArray
    clock_bias_s: AnyArray  # (K, N)
    clock_jumps_s: AnyArray  # (K, N)

    @classmethod
    def empty(cls, n_epochs: int, n_rx: int, sats: list[str], clocks: ReceiverClocks) -> Diagnostics:
        shp = (n_epochs, n_rx, len(sats))
        return cls(
            sats=sats,
            state=np.full(shp, NOT_VISIBLE, dtype=np.int8),
            reported=np.zeros(shp, dtype=bool),
            **{k: np.full(shp, np.nan) for k in _DIAG_FIELDS},
            clock_bias_s=clocks.bias,
            clock_jumps_s=clocks.jumps,
        )

    def record(self, k: int, ep: EpochResult) -> None:
        err = ep.errors
        self.state[k] = np.where(ep.above, ep.state, NOT_VISIBLE)
        self.reported[k] = ep.reported
        self.el[k] = ep.el
        self.cn0[k] = ep.cn0
        self.common_m[k] = err.common_m[None, :]
        self.iono_res_m[k] = err.iono_m - err.iono_broadcast_m
        self.tropo_res_m[k] = err.tropo_m - err.tropo_model_m
        self.multipath_m[k] = err.multipath_m
        self.nlos_m[k] = err.nlos_m
        self.noise_m[k] = err.noise_m
        self.code_sigma_m[k] = err.code_sigma_m
