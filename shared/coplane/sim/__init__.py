"""Fleet scenario simulator: road, vehicles, urban canyon, GNSS errors and UWB -> a fleet recording.

Public API:
  simulate(scenario, out_dir, vehicles=4, duration_s=600, seed=0, progress=False) -> Path
  run_simulation(...) -> SimResult (in memory, optional per-measurement diagnostics)
  write_recording(result, out_dir) -> Path
  ensure_default_recording() -> Path (the bundled 4-vehicle, 10-minute urban-loop recording)
  SCENARIOS, get_scenario(name), Scenario
See docs/simulator.md for the models and where their numbers come from.
"""

from __future__ import annotations

from coplane.sim.generate import ensure_default_recording, run_simulation, simulate
from coplane.sim.result import SimResult
from coplane.sim.scenarios import DEFAULT_SCENARIO, SCENARIOS, Scenario, get_scenario
from coplane.sim.write import write_recording

__all__ = [
    "DEFAULT_SCENARIO",
    "SCENARIOS",
    "Scenario",
    "SimResult",
    "ensure_default_recording",
    "get_scenario",
    "run_simulation",
    "simulate",
    "write_recording",
]
