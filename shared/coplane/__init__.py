"""coplane: plane-constraint-aided cooperative GNSS positioning for vehicle fleets.

The library is pure (no service I/O beyond small bus helpers): recording I/O, GNSS models,
road-plane construction, the factor-graph estimator, baselines, evaluation and the simulator.
Importing it limits BLAS to one thread per process (`coplane.blas_threads`: coplane uses cores
through processes).
"""

from coplane.blas_threads import limit_blas_threads

__version__ = "0.1.0"

limit_blas_threads()
