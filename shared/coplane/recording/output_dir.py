"""The output folder of a command that writes a whole recording (`coplane simulate`, `convert`).

Such a folder is new, empty, or an earlier output of the same command, which is replaced whole:
a 2-vehicle run over a 3-vehicle one, or an RTCM 3 conversion over a UBX one, must not leave the
old vehicles' files beside the new ones, where `coplane recording init` would take them for the
same drive. Files the command never wrote (an eval's output inside, say) stay. Any other folder is
refused before the work starts: the command would mix its files into someone else's, or delete
them. What marks an earlier output is a hidden file naming the command, written before anything
else (so an output cut short is one too), never the recording's name, which a user may choose.
"""

from __future__ import annotations

import shutil
import tomllib
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from coplane.errors import ConfigError

MANIFEST = "fleet.toml"
MARKER = ".coplane-output"  # holds the name of the command that writes the folder


def check_output(out: Path, command: str) -> bool:
    """Whether `out` holds an earlier output of `command` to replace; raise ConfigError for a
    folder that may not be written into."""
    if not out.exists():
        return False
    if not out.is_dir():
        raise ConfigError(f"{out}: not a directory, cannot write a recording into it")
    entries = sorted(p.name for p in out.iterdir())
    if not entries:
        return False
    if _marked(out) != command:
        shown = ", ".join(entries[:5]) + (", ..." if len(entries) > 5 else "")
        raise ConfigError(
            f"{out} holds {shown} and no earlier output of `coplane {command}`: write into a new or"
            " empty folder (its files would mix with the new recording's)"
        )
    return True


def prepare_output(out: Path, command: str, parts: Iterable[str]) -> None:
    """Make `out` ready for a new recording of `command`: the files an earlier one listed in its
    fleet.toml and the command's fixed `parts` (top-level names it always writes) are removed,
    then the folder is marked as this command's (`check_output` says which folders qualify)."""
    if check_output(out, command):
        root = out.resolve()
        listed = [p for p in _listed(out) if p.resolve().is_relative_to(root)]
        for path in [*(out / p for p in parts), *listed]:
            if path.is_dir() and not path.is_symlink():
                shutil.rmtree(path)
            elif path.exists() or path.is_symlink():
                path.unlink()
                _prune_empty(path.parent, root)
        (out / MANIFEST).unlink(missing_ok=True)
    out.mkdir(parents=True, exist_ok=True)
    (out / MARKER).write_text(command + "\n", encoding="utf-8")


def _marked(out: Path) -> str | None:
    try:
        return (out / MARKER).read_text(encoding="utf-8").strip()
    except (OSError, UnicodeDecodeError):
        return None


def _manifest(out: Path) -> dict[str, Any] | None:
    try:
        return tomllib.loads((out / MANIFEST).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
        return None


def _listed(out: Path) -> list[Path]:
    """The files an earlier fleet.toml in `out` names (vehicles, truth, base, navigation, ranges)."""
    m = _manifest(out) or {}
    names: list[object] = []
    for v in m.get("vehicles", []) if isinstance(m.get("vehicles"), list) else []:
        if isinstance(v, dict):
            names += [v.get("obs"), v.get("truth")]
    for section, key in (("base", "obs"), ("uwb", "file")):
        if isinstance(m.get(section), dict):
            names.append(m[section].get(key))
    nav = m.get("nav")
    if isinstance(nav, dict) and isinstance(nav.get("files"), list):
        names += nav["files"]
    return [out / n for n in names if isinstance(n, str) and n]


def _prune_empty(folder: Path, root: Path) -> None:
    """Remove `folder` and its parents up to `root` while they are empty."""
    while folder.resolve() != root and folder.is_dir() and not any(folder.iterdir()):
        folder.rmdir()
        folder = folder.parent
