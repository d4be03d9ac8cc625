"""python -m coplane.vehicle_agent --recording DIR --vehicle_id u1 [--method pc] [--pace lockstep|realtime]

Exits 130 on SIGINT and 143 on SIGTERM (coplane.runtime.stop_event), after a clean stop.
"""

from __future__ import annotations

import sys

from coplane.runtime import exit_code, service_main, setup_logging, steady_state_gc, stop_event


def main(argv: list[str] | None = None) -> int:
    stop = stop_event()  # first: a signal during the imports below still ends the process cleanly
    from .agent import VehicleAgent
    from .settings import AgentSettings

    settings = AgentSettings(_cli_parse_args=argv if argv is not None else sys.argv[1:])  # type: ignore[call-arg]
    setup_logging(f"agent-{settings.vehicle_id}", settings.log_level)
    agent = VehicleAgent(settings, stop)
    steady_state_gc()  # started: what the collector need not scan again
    agent.run()
    return exit_code()


if __name__ == "__main__":
    raise SystemExit(service_main("agent", main))
