"""A batch of linearised measurements for the EKF baselines, and the result of gating it."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from coplane.typing import Mat, Vec


@dataclass
class Rows:
    """A batch of linearised measurements: innovation nu = z - h(x), Jacobian H, covariance R.

    R is block diagonal over the blocks added (a block may be fully correlated, e.g. the double
    differences); `groups` are the gating units (row indices tested together with a chi-square of
    their size), each with a kind (for counts) and the vehicles it concerns.
    """

    n_state: int
    nu: list[float] = field(default_factory=list)
    h: list[Vec] = field(default_factory=list)
    r_blocks: list[Mat] = field(default_factory=list)
    groups: list[tuple[list[int], str, tuple[str, ...]]] = field(default_factory=list)

    def add(
        self,
        nu: Sequence[float],
        h: Sequence[Vec],
        r: Mat,
        kind: str,
        vehicles: tuple[str, ...],
        per_row: bool = False,
    ) -> None:
        """Add rows with covariance block r: one gating group, or one per row (`per_row`)."""
        i0 = len(self.nu)
        n = len(nu)
        self.nu.extend(float(x) for x in nu)
        self.h.extend(h)
        self.r_blocks.append(np.atleast_2d(np.asarray(r, dtype=float)))
        if per_row:
            self.groups.extend(([i0 + k], kind, vehicles) for k in range(n))
        else:
            self.groups.append((list(range(i0, i0 + n)), kind, vehicles))

    def __len__(self) -> int:
        return len(self.nu)


@dataclass
class GateResult:
    accepted: list[int]  # group indices
    rejected: list[int]
