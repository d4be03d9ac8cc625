"""Work spread over several processes of one service: the fusion server's cluster smoothers.

A shell around the pure core: the estimator (`coplane.fgo`) takes any `Smoothers`, and the fusion
server, benchmarks and tests hand it a `SmootherPool` when asked for more than one process.
"""

from coplane.parallel.smoother_pool import SmootherPool, smoothers_for

__all__ = ["SmootherPool", "smoothers_for"]
