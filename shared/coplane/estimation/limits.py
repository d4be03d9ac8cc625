"""Plausibility limits for untrusted estimator inputs: one definition for every boundary.

The wire models (`coplane.messages`), `validate_epoch` (every estimator's input check), the
recording manifest and the HTTP API all take their bounds from here, so a value accepted at one
boundary is never rejected at the next for a different limit.
"""

from __future__ import annotations

import re

# Identifiers -------------------------------------------------------------------------------
VEHICLE_ID_PATTERN = r"^[A-Za-z0-9_-]{1,32}$"  # a Zenoh key chunk, a file stem and a URL segment
VEHICLE_ID = re.compile(VEHICLE_ID_PATTERN)
# GNSS systems an estimator keeps a receiver clock for (RINEX system letters)
KNOWN_SYSTEMS = frozenset("GCERJIS")

# Geometry (metres from the Earth's centre) -----------------------------------------------------
SAT_RADIUS_M = (1.0e7, 5.0e7)  # GNSS orbits: GPS about 2.66e7, BeiDou GEO/IGSO about 4.22e7
RECEIVER_RADIUS_M = (5.0e6, 8.0e6)  # a road vehicle's antenna, with margin for bad SPP fixes

# Measurements ----------------------------------------------------------------------------------
MAX_PSEUDORANGE_M = 1.0e8  # corrected pseudorange magnitude
MAX_SAT_CLOCK_S = 1.0  # satellite clock offset magnitude
MAX_SIGMA_M = 1.0e4  # any 1-sigma in metres (pseudorange, range, plane)
MAX_SPEED_MPS = 200.0  # a road vehicle's speed (Doppler velocity)
MAX_DRIFT_MPS = 1.0e5  # receiver clock drift, m/s
MAX_RANGE_M = 1.0e5  # an inter-vehicle range
