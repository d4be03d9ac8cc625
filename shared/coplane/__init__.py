"""coplane: plane-constraint-aided cooperative GNSS positioning for vehicle fleets.

The library is pure (no service I/O beyond small bus helpers): recording I/O, GNSS models,
road-plane construction, the factor-graph estimator, baselines, evaluation and the simulator.
"""

__version__ = "0.1.0"
