"""Plausibility limits for untrusted estimator inputs: one definition for every boundary.

The wire models (`coplane.messages`), `validate_epoch` (every estimator's input check), the
recording manifest and the HTTP API all take their bounds from here, so a value accepted at one
boundary is never rejected at the next for a different limit.
"""

from __future__ import annotations

# Identifiers (vehicle and fleet ids: coplane.ids) ------------------------------------------
# GNSS systems an estimator keeps a receiver clock for (RINEX system letters)
KNOWN_SYSTEMS = frozenset("GCERJIS")
SAT_ID_PATTERN = r"^[CEGIJRS][0-9]{2}$"  # a satellite of a known system, RINEX 3 style ("G05")

# Geometry (metres from the Earth's centre) -----------------------------------------------------
SAT_RADIUS_M = (1.0e7, 5.0e7)  # GNSS orbits: GPS about 2.66e7, BeiDou GEO/IGSO about 4.22e7
RECEIVER_RADIUS_M = (5.0e6, 8.0e6)  # a road vehicle's antenna, with margin for bad SPP fixes

# Measurements ----------------------------------------------------------------------------------
PSEUDORANGE_M = (1.0e7, 6.0e7)  # raw or corrected, GPS to BeiDou GEO, with receiver clock margin
MAX_SAT_CLOCK_S = 1.0  # satellite clock offset magnitude
MAX_SIGMA_M = 1.0e4  # a pseudorange 1-sigma (down-weighted NLOS can be large)
MAX_SPEED_MPS = 200.0  # a road vehicle's speed (Doppler velocity)
MAX_DRIFT_MPS = 1.0e5  # receiver clock drift, m/s
MAX_RANGE_M = 2.0e3  # an inter-vehicle (UWB) range
MAX_RANGE_SIGMA_M = 100.0  # its 1-sigma
MAX_PLANE_SIGMA_M = 100.0  # a road plane's 1-sigma at the antenna
MAX_ANTENNA_HEIGHT_M = 10.0  # an antenna's height above the road
MAX_NORMAL_ERROR = 1e-6  # a plane normal's length may differ this much from 1 (SVD gives ~1e-16)
