"""What a service loads before its first message (docs/performance-scale.md, "Start-up"): a fusion
server and the API never run a baseline filter or the standstill test, so they must not pay for
scipy.stats (half a second, about 40 MB) or scipy.linalg at every start."""

from __future__ import annotations

import pytest
from support.fresh_python import fresh_python

HEAVY = ("scipy.stats", "scipy.linalg", "scipy.optimize", "coplane.baselines")


@pytest.mark.parametrize("module", ["coplane.fusion_server.server", "coplane.api.app"])
def test_service_imports_leave_out_what_it_never_runs(module: str) -> None:
    code = f"import sys, {module}; print(' '.join(m for m in {HEAVY!r} if m in sys.modules))"
    out = fresh_python(code)
    assert out == "", f"{module} loads {out}"


def test_a_baseline_is_still_built_by_name() -> None:
    """The baselines are imported when their method is built, not when the registry is."""
    from coplane.methods import get_method

    for name in ("non-cp-ekf", "dd-cp", "gamp-cp"):
        spec = get_method(name)
        assert spec.factory is not None
        assert type(spec.factory()).__module__.startswith("coplane.baselines")


def test_an_agent_loads_the_standstill_modules_when_it_starts() -> None:
    """An agent runs the standstill test, whose first power computation needs scipy.stats: the
    agent and the load generator load it at start (`load_dependencies`), not mid-run."""
    code = (
        "import sys\n"
        "from coplane.gnss.standstill import load_dependencies, noncentrality\n"
        "assert 'scipy.stats' not in sys.modules\n"
        "load_dependencies()\n"
        "before = set(sys.modules)\n"
        "noncentrality(0.01, 0.8, 5)\n"
        "print(sorted(m for m in set(sys.modules) - before if m.startswith('scipy')))"
    )
    assert fresh_python(code) == "[]"


def test_agents_load_the_standstill_modules_when_they_are_built() -> None:
    """The agent and the load generator call `load_dependencies` when they are built (the bundled
    recording; neither touches the bus before `run`): their import alone does not load scipy.stats,
    building them does."""
    code = (
        "import sys\n"
        "from coplane.sim.generate import bundled_default_path\n"
        "from coplane.vehicle_agent.agent import VehicleAgent\n"
        "from coplane.vehicle_agent.loadgen import LoadGenerator\n"
        "from coplane.vehicle_agent.settings import AgentSettings, LoadgenSettings\n"
        "rec = bundled_default_path()\n"
        "sys.modules.pop('scipy.stats', None)\n"
        "VehicleAgent(AgentSettings(recording=rec, vehicle_id='u1', method='pc'))\n"
        "agent = 'scipy.stats' in sys.modules\n"
        "sys.modules.pop('scipy.stats', None)\n"
        "LoadGenerator(LoadgenSettings(recording=rec))\n"
        "print(agent, 'scipy.stats' in sys.modules)"
    )
    assert fresh_python(code).split()[-2:] == ["True", "True"]
