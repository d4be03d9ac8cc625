"""python -m coplane.router --listen tcp/127.0.0.1:7447 : a Zenoh router as a Python process.

Tests and `coplane fleet` use it where docker-compose uses the official eclipse/zenoh image.
"""

from __future__ import annotations

import argparse

from coplane.bus import open_router
from coplane.runtime import setup_logging, stop_event


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m coplane.router")
    ap.add_argument(
        "--listen", action="append", default=None, help="endpoint, repeatable (default tcp/127.0.0.1:7447)"
    )
    args = ap.parse_args(argv)
    log = setup_logging("router")
    stop = stop_event()
    session = open_router(args.listen or ["tcp/127.0.0.1:7447"])
    log.info("router up", extra={"listen": ",".join(args.listen or [])})
    stop.wait()
    session.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
