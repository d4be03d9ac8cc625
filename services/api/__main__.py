"""python -m coplane.api [--recording DIR | --fleet ID] [--connect '["tcp/127.0.0.1:7447"]'] [--port 8000]

Exits 130 on SIGINT and 143 on SIGTERM after a graceful stop (open /stream responses ended, the
bus session closed), within coplane.runtime.STOP_GRACE_S.
"""

from __future__ import annotations

import asyncio
import contextlib
import signal
import socket
import sys
import threading
from collections.abc import Iterator
from types import FrameType
from typing import TYPE_CHECKING

import uvicorn

from coplane.runtime import (
    STOP_GRACE_S,
    exit_code,
    notify_signal,
    received_signal,
    service_main,
    setup_logging,
    stop_event,
)

if TYPE_CHECKING:
    from .hub import StreamHub


class _Server(uvicorn.Server):
    """Ends open /stream responses on SIGTERM/SIGINT (uvicorn waits for them before it stops), and
    records the signal for the exit code instead of re-raising it as uvicorn does."""

    hub: StreamHub | None = None
    _loop: asyncio.AbstractEventLoop | None = None

    def handle_exit(self, sig: int, frame: FrameType | None) -> None:
        notify_signal(sig)
        hub = self.hub
        if hub is not None and self._loop is not None:
            self._loop.call_soon_threadsafe(hub.close)
        super().handle_exit(sig, frame)

    @contextlib.contextmanager
    def capture_signals(self) -> Iterator[None]:
        if threading.current_thread() is not threading.main_thread():
            yield
            return
        handled = (signal.SIGINT, signal.SIGTERM)
        original = {sig: signal.signal(sig, self.handle_exit) for sig in handled}
        try:
            yield
        finally:
            for sig, handler in original.items():
                signal.signal(sig, handler)

    async def serve(self, sockets: list[socket.socket] | None = None) -> None:
        self._loop = asyncio.get_running_loop()
        if received_signal() is not None:  # it came before uvicorn's handlers were in place
            self.should_exit = True
        await super().serve(sockets)


def main(argv: list[str] | None = None) -> int:
    stop = stop_event()  # first: a signal during the imports below still ends the process cleanly
    from .app import create_app
    from .settings import ApiSettings

    settings = ApiSettings(_cli_parse_args=argv if argv is not None else sys.argv[1:])  # type: ignore[call-arg]
    setup_logging("api", settings.log_level)
    if stop.is_set():
        return exit_code()
    app = create_app(settings)
    config = uvicorn.Config(
        app,
        host=settings.host,
        port=settings.port,
        log_config=None,  # keep the JSON-lines root handler from setup_logging
        access_log=settings.access_log,
        timeout_graceful_shutdown=max(1, int(STOP_GRACE_S) - 1),
        lifespan="on",
    )
    server = _Server(config)
    server.hub = app.state.hub
    server.run()
    return exit_code()


if __name__ == "__main__":
    raise SystemExit(service_main("api", main))
