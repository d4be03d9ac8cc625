"""python -m coplane.bus.router --listen tcp/127.0.0.1:7447 : a Zenoh router as a Python process.

Tests and `coplane fleet` use it where docker-compose uses the official eclipse/zenoh image.
"""

from __future__ import annotations

import argparse

import zenoh

from coplane.bus.config import router_config
from coplane.runtime import setup_logging, stop_event

DEFAULT_LISTEN = "tcp/127.0.0.1:7447"


def open_router(listen: list[str]) -> zenoh.Session:
    """A Zenoh router inside this Python process."""
    return zenoh.open(router_config(listen))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m coplane.bus.router")
    ap.add_argument(
        "--listen", action="append", default=None, help=f"endpoint, repeatable (default {DEFAULT_LISTEN})"
    )
    args = ap.parse_args(argv)
    log = setup_logging("router")
    stop = stop_event()
    session = open_router(args.listen or [DEFAULT_LISTEN])
    log.info("router up", extra={"listen": ",".join(args.listen or [])})
    stop.wait()
    session.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
