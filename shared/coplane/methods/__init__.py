"""Named methods (the paper's and the baselines) and the ranging-interruption experiment."""

from coplane.methods.interruption import INTERRUPTION_BLOCK, interrupt_range
from coplane.methods.registry import METHODS, MethodSpec, PlaneSource, get_method

__all__ = ["INTERRUPTION_BLOCK", "METHODS", "MethodSpec", "PlaneSource", "get_method", "interrupt_range"]
