"""python -m coplane.vehicle_agent --recording DIR --vehicle_id u1 [--method pc] [--pace lockstep|realtime]"""

from __future__ import annotations

import sys

from coplane.runtime import setup_logging, stop_event

from .agent import VehicleAgent
from .settings import AgentSettings


def main(argv: list[str] | None = None) -> int:
    settings = AgentSettings(_cli_parse_args=argv if argv is not None else sys.argv[1:])  # type: ignore[call-arg]
    setup_logging(f"agent-{settings.vehicle_id}", settings.log_level)
    VehicleAgent(settings, stop_event()).run()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
