"""python -m coplane.fusion_server --recording DIR [--method pc] [--pace lockstep|realtime]"""

from __future__ import annotations

import sys

from coplane.runtime import setup_logging, stop_event

from .server import FusionServer
from .settings import FusionSettings


def main(argv: list[str] | None = None) -> int:
    settings = FusionSettings(_cli_parse_args=argv if argv is not None else sys.argv[1:])  # type: ignore[call-arg]
    setup_logging("fusion", settings.log_level)
    FusionServer(settings, stop_event()).run()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
