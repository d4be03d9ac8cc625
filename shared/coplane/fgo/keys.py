"""GTSAM keys for (vehicle, epoch index, kind), collision-free while vehicles join and leave.

A key is `gtsam.symbol(chr, index)` with index = slot << 32 | step: `slot` is a small integer given
to a vehicle id the first time it is seen (never reused), `step` the estimator's epoch counter.
Kinds: 'p' for the ECEF position (Point3), one lower-case letter per GNSS system for that
system's receiver clock (double, seconds): 'g' GPS, 'c' BeiDou, ..., and the same letter in upper
case for its offset from the receiver clock (double, metres; `FgoConfig.clock_isb_sigma_m`).
"""

from __future__ import annotations

import gtsam
import numpy as np

from coplane.gnss.constants import C

STEP_BITS = 32
SLOT_BITS = 24  # gtsam.Symbol indices have 56 bits
MAX_STEP = (1 << STEP_BITS) - 1
MAX_SLOT = (1 << SLOT_BITS) - 1

POSITION_CHR = "p"
CLOCK_CHR: dict[str, str] = {"G": "g", "R": "r", "E": "e", "C": "c", "J": "j", "I": "i", "S": "s"}
# a system's offset from the receiver clock, c (dt_ref - dt_system) (metres; FgoConfig.clock_isb_sigma_m)
BIAS_CHR: dict[str, str] = {s: c.upper() for s, c in CLOCK_CHR.items()}
_KIND_OF_CHR = {
    POSITION_CHR: "position",
    **{c: f"clock-{s}" for s, c in CLOCK_CHR.items()},
    **{c: f"bias-{s}" for s, c in BIAS_CHR.items()},
}


def relinearize_thresholds(position_m: float) -> gtsam.ISAM2ThresholdMap:
    """iSAM2's relinearisation threshold per kind of key, all equal to `position_m` in metres.

    A single number would be compared with every variable's delta in its own unit, and a clock
    is in seconds: 0.01 there is 3000 km, so a clock was never relinearised and the Huber weights
    of its pseudoranges stayed at the clock's first guess. iSAM2 then stopped 0.2-0.5 m (and a
    higher cost) away from the optimum of the same graph (checked against batch Gauss-Newton on
    rebuilt city clusters). Every kind made here has an entry: GTSAM looks a key's character up in
    the map without a default.
    """
    thresholds = gtsam.ISAM2ThresholdMap()
    thresholds.insert((POSITION_CHR, np.full(3, position_m)))
    for c in CLOCK_CHR.values():
        thresholds.insert((c, np.full(1, position_m / C)))
    for c in BIAS_CHR.values():  # a system's offset from the receiver clock is in metres
        thresholds.insert((c, np.full(1, position_m)))
    return thresholds


def _index(slot: int, step: int) -> int:
    if not 0 <= slot <= MAX_SLOT:
        raise ValueError(f"vehicle slot {slot} out of range 0..{MAX_SLOT}")
    if not 0 <= step <= MAX_STEP:
        raise ValueError(f"epoch step {step} out of range 0..{MAX_STEP}")
    return (slot << STEP_BITS) | step


def position_key(slot: int, step: int) -> int:
    return int(gtsam.symbol(POSITION_CHR, _index(slot, step)))


def clock_key(slot: int, step: int, system: str) -> int:
    """Receiver clock of one GNSS system (its own inter-system bias is absorbed here)."""
    return _system_key(CLOCK_CHR, slot, step, system)


def bias_key(slot: int, step: int, system: str) -> int:
    """One GNSS system's offset from the vehicle's receiver clock, c (dt_ref - dt_system), metres."""
    return _system_key(BIAS_CHR, slot, step, system)


def _system_key(chars: dict[str, str], slot: int, step: int, system: str) -> int:
    try:
        c = chars[system]
    except KeyError:
        raise ValueError(f"unknown GNSS system {system!r}; known: {''.join(chars)}") from None
    return int(gtsam.symbol(c, _index(slot, step)))


def is_position_key(key: int) -> bool:
    """Whether a key made here is a position (Point3) rather than a clock (double): its character
    is the top byte, read without building a gtsam.Symbol (called per key when values are packed)."""
    return key >> (SLOT_BITS + STEP_BITS) == ord(POSITION_CHR)


def decode_key(key: int) -> tuple[str, int, int]:
    """(kind, slot, step) of a key made here, e.g. ("clock-G", 3, 120)."""
    s = gtsam.Symbol(key)
    kind = _KIND_OF_CHR.get(chr(s.chr()), f"unknown-{chr(s.chr())}")
    idx = int(s.index())
    return kind, idx >> STEP_BITS, idx & MAX_STEP


class KeyRegistry:
    """Vehicle id -> slot, assigned in first-seen order and never reused (keys stay unique)."""

    def __init__(self) -> None:
        self._slots: dict[str, int] = {}

    def slot(self, vehicle_id: str) -> int:
        s = self._slots.get(vehicle_id)
        if s is None:
            s = len(self._slots)
            if s > MAX_SLOT:
                raise ValueError("too many distinct vehicle ids for the key space")
            self._slots[vehicle_id] = s
        return s

    def vehicle(self, slot: int) -> str | None:
        for vid, s in self._slots.items():
            if s == slot:
                return vid
        return None

    def __len__(self) -> int:
        return len(self._slots)
