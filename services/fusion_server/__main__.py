"""python -m coplane.fusion_server --recording DIR [--method pc] [--pace lockstep|realtime]

Exits 130 on SIGINT and 143 on SIGTERM (coplane.runtime.stop_event), after a clean stop.
"""

from __future__ import annotations

import sys

from coplane.allocator import loaded_allocator
from coplane.runtime import exit_code, service_main, setup_logging, steady_state_gc, stop_event


def main(argv: list[str] | None = None) -> int:
    stop = stop_event()  # first: a signal during the imports below still ends the process cleanly
    from .server import FusionServer, log
    from .settings import FusionSettings

    settings = FusionSettings(_cli_parse_args=argv if argv is not None else sys.argv[1:])  # type: ignore[call-arg]
    setup_logging("fusion", settings.log_level)
    # jemalloc unless the machine lacks it or COPLANE_ALLOCATOR says otherwise (coplane.allocator)
    log.info("memory allocator", extra={"allocator": loaded_allocator()})
    server = FusionServer(settings, stop)
    steady_state_gc()  # started: what the collector need not scan again
    server.run()
    return exit_code()


if __name__ == "__main__":
    raise SystemExit(service_main("fusion", main))
