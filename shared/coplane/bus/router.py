"""python -m coplane.bus.router --listen tcp/127.0.0.1:7447 : a Zenoh router as a Python process.

Tests and `coplane fleet` use it where docker-compose uses the official eclipse/zenoh image.
Secure when `COPLANE_BUS_CERTS` names a certificates folder (coplane.bus.security): it then
listens on TLS only (a `tcp/` endpoint becomes `tls/`), requires client certificates from the
folder's CA and applies the access control of coplane.bus.acl to every vehicle certificate in the
folder (`--fleet` restricts the keys to one fleet). Without certificates it warns, loudly.
"""

from __future__ import annotations

import argparse

import zenoh

from coplane.bus.config import router_config
from coplane.bus.security import BusSecurity, current_security, warn_insecure
from coplane.runtime import exit_code, setup_logging, stop_event

DEFAULT_LISTEN = "tcp/127.0.0.1:7447"


def open_router(
    listen: list[str], security: BusSecurity | None = None, fleet: str = "*", connect: list[str] | None = None
) -> zenoh.Session:
    """A Zenoh router inside this Python process (secure per `security`, default the environment),
    meshed with the routers at `connect`."""
    return zenoh.open(router_config(listen, security, fleet=fleet, connect=connect or []))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m coplane.bus.router")
    ap.add_argument(
        "--listen", action="append", default=None, help=f"endpoint, repeatable (default {DEFAULT_LISTEN})"
    )
    ap.add_argument("--fleet", default="*", help="grant keys of this fleet only (default: any fleet)")
    ap.add_argument("--connect", action="append", default=[], help="another router to mesh with, repeatable")
    args = ap.parse_args(argv)
    log = setup_logging("router")
    stop = stop_event()
    security = current_security()
    if not security.secure:
        warn_insecure("router")
    listen = args.listen or [DEFAULT_LISTEN]
    try:
        session = open_router(listen, security, args.fleet, args.connect)
    except zenoh.ZError as exc:  # a malformed --listen / --connect endpoint, a port in use
        log.error(
            "router could not start",
            extra={
                "listen": ",".join(listen),
                "mesh": ",".join(args.connect),
                "error": str(exc).split(" at /")[0],
            },
        )
        return 2
    log.info(
        "router up",
        extra={"listen": ",".join(listen), "mesh": ",".join(args.connect), "secure": security.secure},
    )
    stop.wait()
    session.close()
    return exit_code()


if __name__ == "__main__":
    raise SystemExit(main())
