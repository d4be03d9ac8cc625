"""Process plumbing shared by the services: JSON-lines logs, clean shutdown and layered settings."""

from __future__ import annotations

import json
import logging
import os
import signal
import sys
import threading
import time
from pathlib import Path
from typing import Any

from pydantic_settings import (
    BaseSettings,
    PydanticBaseSettingsSource,
    SettingsConfigDict,
    TomlConfigSettingsSource,
)

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


def stop_event() -> threading.Event:
    """An Event set on SIGTERM or SIGINT, so main loops end cleanly (tokens undeclared, files closed)."""
    ev = threading.Event()

    def _handler(signum: int, _frame: Any) -> None:
        logging.getLogger("coplane").info("signal received, stopping", extra={"signal": signum})
        ev.set()

    signal.signal(signal.SIGTERM, _handler)
    signal.signal(signal.SIGINT, _handler)
    return ev


# -- configuration -------------------------------------------------------------------------------


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
