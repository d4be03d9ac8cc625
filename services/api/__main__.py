"""python -m coplane.api [--recording DIR | --fleet ID] [--connect '["tcp/127.0.0.1:7447"]'] [--port 8000]"""

from __future__ import annotations

import asyncio
import socket
import sys
from types import FrameType

import uvicorn

from coplane.runtime import setup_logging

from .app import create_app
from .hub import StreamHub
from .settings import ApiSettings


class _Server(uvicorn.Server):
    """Ends open /stream responses on SIGTERM/SIGINT: uvicorn waits for them before it stops."""

    hub: StreamHub | None = None
    _loop: asyncio.AbstractEventLoop | None = None

    def handle_exit(self, sig: int, frame: FrameType | None) -> None:
        hub = self.hub
        if hub is not None and self._loop is not None:
            self._loop.call_soon_threadsafe(hub.close)
        super().handle_exit(sig, frame)

    async def serve(self, sockets: list[socket.socket] | None = None) -> None:
        self._loop = asyncio.get_running_loop()
        await super().serve(sockets)


def main(argv: list[str] | None = None) -> int:
    settings = ApiSettings(_cli_parse_args=argv if argv is not None else sys.argv[1:])  # type: ignore[call-arg]
    setup_logging("api", settings.log_level)
    app = create_app(settings)
    config = uvicorn.Config(
        app,
        host=settings.host,
        port=settings.port,
        log_config=None,  # keep the JSON-lines root handler from setup_logging
        access_log=settings.access_log,
        timeout_graceful_shutdown=3,
        lifespan="on",
    )
    server = _Server(config)
    server.hub = app.state.hub
    server.run()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
