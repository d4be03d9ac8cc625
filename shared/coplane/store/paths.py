"""Where the services keep their logs when the operator does not say: one file per fleet, service
and router, under the state directory (`$COPLANE_STATE_DIR`, else `$XDG_STATE_HOME/coplane`, else
`~/.local/state/coplane`), never inside the working tree."""

from __future__ import annotations

import os
import re
from collections.abc import Sequence
from pathlib import Path

DISABLED = ("", "none", "off")


def default_state_dir() -> Path:
    env = os.environ.get("COPLANE_STATE_DIR")
    if env:
        return Path(env)
    xdg = os.environ.get("XDG_STATE_HOME")
    return (Path(xdg) if xdg else Path.home() / ".local" / "state") / "coplane"


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9.-]+", "-", text).strip("-")[:80] or "x"


def log_path(setting: str | None, *parts: str, connect: Sequence[str] = ()) -> Path | None:
    """The log file a `db` setting names: None when disabled (`none`, `off` or empty), the path as
    given, or for `auto` `<state dir>/<parts>-<router>.sqlite`. The router endpoint is part of the
    default name so fleets on different routers (tests on free ports) never share a file."""
    if setting is None or setting.strip().lower() in DISABLED:
        return None
    if setting != "auto":
        return Path(setting).expanduser()
    name = "-".join(_slug(p) for p in (*parts, *(connect[:1] or ["local"])))
    return default_state_dir() / f"{name}.sqlite"


def map_path(setting: str | Path | None, fleet: str) -> Path | None:
    """The road map a `map` setting names: None when disabled, the path as given, or for `auto`
    `<state dir>/map-<fleet>.sqlite`. Unlike a solution log it is not per router: the map is about
    the fleet's roads and keeps learning across runs (evidence counts once, docs/roadmap.md)."""
    if setting is None:
        return None
    text = str(setting)
    if text.strip().lower() in DISABLED:
        return None
    if text != "auto":
        return Path(text).expanduser()
    return default_state_dir() / f"map-{_slug(fleet)}.sqlite"


def server_map_path(base: Path, server_id: str) -> Path:
    """With several fusion servers by region: server `server_id`'s replica of the map `base`,
    beside it (`map-x.sqlite` -> `map-x.s1.sqlite`; docs/scale.md, "The road map across servers")."""
    return base.with_name(f"{base.stem}.{server_id}{base.suffix}")
