"""Process plumbing shared by the services: JSON-lines logs (and rate-limited ones), clean shutdown and
layered settings."""

from __future__ import annotations

import contextlib
import gc
import json
import logging
import os
import signal
import sys
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Hashable, Iterator
from pathlib import Path
from typing import Annotated, Any

from pydantic import AfterValidator, BaseModel, Field
from pydantic_settings import (
    BaseSettings,
    PydanticBaseSettingsSource,
    SettingsConfigDict,
    TomlConfigSettingsSource,
)

from coplane.regions import RegionConfig

_STD = set(logging.LogRecord("", 0, "", 0, "", (), None).__dict__) | {"message", "asctime"}


class JsonFormatter(logging.Formatter):
    """One JSON object per line: ts, level, logger, msg, plus any `extra=` fields."""

    def __init__(self, service: str) -> None:
        super().__init__()
        self.service = service

    def format(self, record: logging.LogRecord) -> str:
        out: dict[str, Any] = {
            "ts": round(time.time(), 3),
            "level": record.levelname.lower(),
            "service": self.service,
            "logger": record.name,
            "msg": record.getMessage(),
        }
        for k, v in record.__dict__.items():
            if k not in _STD and not k.startswith("_"):
                out[k] = v if isinstance(v, (str, int, float, bool, type(None))) else str(v)
        if record.exc_info:
            out["exc"] = self.formatException(record.exc_info)
        return json.dumps(out)


def setup_logging(service: str, level: str = "INFO") -> logging.Logger:
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(JsonFormatter(service))
    root = logging.getLogger()
    root.handlers[:] = [handler]
    root.setLevel(level.upper())
    return logging.getLogger(f"coplane.{service}")


# -- rate-limited logging --------------------------------------------------------------------------
# A hostile or broken sender can make a service reject thousands of messages a second; logging each
# would fill the disk and bury everything else. The counts belong in metrics, not in the log.


class RateLimitedLog:
    """At most one record per key per `every_s`, with the number suppressed since the last one."""

    def __init__(
        self,
        logger: logging.Logger,
        every_s: float = 10.0,
        max_keys: int = 1024,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.logger = logger
        self.every_s = every_s
        self.max_keys = max_keys
        self.clock = clock
        self._last: OrderedDict[Hashable, tuple[float, int]] = OrderedDict()  # key -> (logged at, suppressed)
        self.suppressed = 0  # in total, for tests and metrics

    def log(self, level: int, key: Hashable, msg: str, extra: dict[str, Any] | None = None) -> bool:
        """Log `msg` unless this key was logged less than `every_s` ago; True if it was logged."""
        now = self.clock()
        last = self._last.get(key)
        if last is not None and now - last[0] < self.every_s:
            self._last[key] = (last[0], last[1] + 1)
            self.suppressed += 1
            return False
        fields = dict(extra or {})
        if last is not None and last[1]:
            fields["suppressed"] = last[1]
        self.logger.log(level, msg, extra=fields)
        self._last[key] = (now, 0)
        self._last.move_to_end(key)
        while len(self._last) > self.max_keys:
            self._last.popitem(last=False)
        return True

    def warning(self, key: Hashable, msg: str, extra: dict[str, Any] | None = None) -> bool:
        """`log` at WARNING."""
        return self.log(logging.WARNING, key, msg, extra)


# -- clean shutdown ------------------------------------------------------------------------------
# Every process stops on SIGINT (Ctrl-C, which the terminal sends to the whole process group) and
# SIGTERM (docker stop, the fleet launcher) within STOP_GRACE_S, and exits 128 + the signal (130,
# 143) as shells report a process a signal ended. The first signal sets the stop event and starts a
# watchdog: what has not finished cleanly by then (a hung session close) is cut short.

STOP_GRACE_S = 3.0
_signals: list[int] = []
_events: list[threading.Event] = []
_watchdog: list[tuple[float, Callable[[], None] | None]] = []  # (grace_s, on_deadline) of stop_event


def received_signal() -> int | None:
    """The first SIGINT/SIGTERM this process received, if any."""
    return _signals[0] if _signals else None


def exit_code(default: int = 0) -> int:
    """128 + the first stop signal received (130 for SIGINT, 143 for SIGTERM), else `default`."""
    sig = received_signal()
    return 128 + sig if sig is not None else default


def _deadline(grace_s: float, on_deadline: Callable[[], None] | None) -> None:
    logging.getLogger("coplane").error("did not stop in time, exiting", extra={"grace_s": grace_s})
    try:
        if on_deadline is not None:
            on_deadline()
    finally:
        logging.shutdown()
        os._exit(exit_code(1))


def notify_signal(signum: int) -> None:
    """Record a stop signal: set the stop events and, on the first one, start the watchdog. For
    code that owns the signal handlers itself (uvicorn in the API)."""
    first = not _signals
    _signals.append(signum)
    logging.getLogger("coplane").info("signal received, stopping", extra={"signal": signum})
    for ev in _events:
        ev.set()
    if first and _watchdog:
        grace_s, on_deadline = _watchdog[-1]
        timer = threading.Timer(grace_s, _deadline, (grace_s, on_deadline))
        timer.daemon = True
        timer.start()


def stop_event(
    grace_s: float | None = STOP_GRACE_S, on_deadline: Callable[[], None] | None = None
) -> threading.Event:
    """An Event set on SIGTERM or SIGINT, so main loops end cleanly (tokens undeclared, files closed).

    `grace_s` after the first signal the process exits with `exit_code()` regardless, after
    `on_deadline` (e.g. killing child processes); None: no watchdog. Later signals are logged only.
    """
    ev = threading.Event()
    if _signals:
        ev.set()
    _events.append(ev)
    if grace_s is not None:
        _watchdog.append((grace_s, on_deadline))
    signal.signal(signal.SIGTERM, lambda signum, _frame: notify_signal(signum))
    signal.signal(signal.SIGINT, lambda signum, _frame: notify_signal(signum))
    return ev


@contextlib.contextmanager
def stop_signals(
    grace_s: float | None = STOP_GRACE_S, on_deadline: Callable[[], None] | None = None
) -> Iterator[threading.Event]:
    """`stop_event` for a block of a longer-lived process (a CLI command run in-process by tests):
    the previous handlers come back when the block ends."""
    previous = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    n_events, n_watchdogs = len(_events), len(_watchdog)
    try:
        yield stop_event(grace_s, on_deadline)
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        del _events[n_events:], _watchdog[n_watchdogs:]


# -- configuration -------------------------------------------------------------------------------

LOG_LEVELS = ("DEBUG", "INFO", "WARNING", "ERROR", "CRITICAL")


def _log_level(value: str) -> str:
    """A log level name in any case, as `logging` knows it: a typo is a settings error naming the
    field, not a traceback from `logging` after the service has started."""
    if value.upper() not in LOG_LEVELS:
        raise ValueError(f"{value!r} is not a log level (one of {', '.join(LOG_LEVELS)})")
    return value.upper()


LogLevel = Annotated[str, AfterValidator(_log_level)]


class ServiceSettings(BaseSettings):
    """Base for service settings: constructor/CLI > environment (COPLANE_<SERVICE>_*) > TOML.

    The TOML file is named by COPLANE_CONFIG; each service reads its own table ([agent],
    [fusion], [api]) so one file can configure a whole fleet deployment.
    """

    model_config = SettingsConfigDict(extra="ignore")
    toml_table: str = ""

    @classmethod
    def settings_customise_sources(
        cls,
        settings_cls: type[BaseSettings],
        init_settings: PydanticBaseSettingsSource,
        env_settings: PydanticBaseSettingsSource,
        dotenv_settings: PydanticBaseSettingsSource,
        file_secret_settings: PydanticBaseSettingsSource,
    ) -> tuple[PydanticBaseSettingsSource, ...]:
        sources: list[PydanticBaseSettingsSource] = [init_settings, env_settings]
        path = os.environ.get("COPLANE_CONFIG")
        table = str(cls.model_fields["toml_table"].default or "")
        if path and Path(path).is_file():
            sources.append(
                TomlConfigSettingsSource(
                    settings_cls, Path(path), toml_table_header=(table,) if table else None
                )
            )
        return tuple(sources)


class RegionOptions(BaseModel):
    """The fleet's region settings (docs/scale.md), the same for every agent and server of a
    fleet: a mixin of the agent's and the fusion server's settings."""

    regions: bool = Field(
        default=False,
        description="Spread the fleet over several fusion servers by region (node keys gain shard/region)",
    )
    region_size_m: float = Field(default=4000.0, ge=100.0, description="Edge of a region (metric grid)")
    region_shards: int = Field(default=64, ge=1, le=4096, description="Buckets of regions servers own")
    region_margin_m: float = Field(
        default=500.0, ge=0.0, description="Near another region, a vehicle also sends its node message there"
    )

    def region_config(self) -> RegionConfig:
        """The settings as a `RegionConfig`; a bad combination is a `ConfigError` naming it."""
        from coplane.errors import ConfigError

        try:
            return RegionConfig(
                size_m=self.region_size_m, shards=self.region_shards, margin_m=self.region_margin_m
            )
        except ValueError as exc:
            raise ConfigError(str(exc)) from exc


# Python's collector by default scans the young objects every 700 net allocations and, every
# few hundred of those, everything a process holds. A service allocates a message's models, arrays
# and factors per vehicle per epoch, almost all freed by reference counting, so the scans found
# little at a real cost in a fusion server's CPU (docs/performance-scale.md, "Server overhead",
# measures the change). Reference cycles are still collected, after 50,000 allocations instead.
GC_YOUNG_THRESHOLD = 50_000


def steady_state_gc() -> None:
    """Once a service process has started (imports, recording): what exists now is kept for the
    process's life, so move it out of the collector's scans (`gc.freeze`) and let the young
    generation grow to `GC_YOUNG_THRESHOLD` before a scan. Process-wide: for a service's entry
    point, never for library code (a test calling a service's `run` keeps the default collector)."""
    gc.collect()
    gc.freeze()
    gc.set_threshold(GC_YOUNG_THRESHOLD, 20, 100)


def service_main(service: str, body: Callable[[], int]) -> int:
    """Run a service's `main` body; a user-fixable problem (`CoplaneError`: a corrupt solution log,
    a bad recording, a wrong option; or invalid settings) ends it with one clear line and the
    error's exit code instead of a traceback. Anything else is a bug and keeps its traceback."""
    from pydantic import ValidationError

    from coplane.errors import CoplaneError

    try:
        return body()
    except CoplaneError as exc:
        logging.getLogger(f"coplane.{service}").error("cannot run: %s", exc)
        print(f"{service}: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except ValidationError as exc:
        print(f"{service}: invalid settings: {exc}", file=sys.stderr)
        return 2
