"""`key=value` changes to a method's factor-graph settings, as typed on a command line.

The opt-in parts of the estimator (road-height links, the one-sided FDE, other solvers) are
`FgoConfig` fields; this lets a user try them on their own recordings without editing code
(`coplane eval --fgo fde_k_long=1.5`). Each value is parsed by its field's type, and the changed
config runs through `FgoConfig`'s own validation, so a bad value is refused with the field's name.
Written here because pydantic-settings parses a whole settings object, not overrides of a frozen
dataclass's fields given as strings.
"""

from __future__ import annotations

import dataclasses
import types
import typing
from collections.abc import Sequence

from coplane.errors import ConfigError
from coplane.fgo.config import FgoConfig

_NONE = ("none", "null", "off")
_TRUE = ("true", "1", "yes", "on")
_FALSE = ("false", "0", "no")


def _parse(name: str, text: str, kind: object) -> object:
    """`text` as a value of the annotated type `kind` (float, int, bool, a Literal, or X | None)."""
    args = typing.get_args(kind)
    if typing.get_origin(kind) in (typing.Union, types.UnionType):
        if text.strip().lower() in _NONE:
            return None
        (inner,) = [a for a in args if a is not type(None)]
        return _parse(name, text, inner)
    if typing.get_origin(kind) is typing.Literal:
        if text not in args:
            raise ConfigError(f"--fgo {name}={text}: expected one of {', '.join(map(str, args))}")
        return text
    if kind is bool:
        low = text.strip().lower()
        if low not in _TRUE + _FALSE:
            raise ConfigError(f"--fgo {name}={text}: expected true or false")
        return low in _TRUE
    try:
        return int(text) if kind is int else float(text)
    except ValueError:
        raise ConfigError(
            f"--fgo {name}={text}: expected {'an integer' if kind is int else 'a number'}"
        ) from None


def parse_fgo_overrides(items: Sequence[str]) -> dict[str, object]:
    """['fde_k_long=1.5', 'height_link_max_m=50'] -> {'fde_k_long': 1.5, 'height_link_max_m': 50.0}.

    Unknown fields and unparsable values raise ConfigError naming the item; the values' ranges are
    checked when the config is built (`apply_fgo_overrides`)."""
    hints = typing.get_type_hints(FgoConfig)
    out: dict[str, object] = {}
    for item in items:
        name, sep, text = item.partition("=")
        name = name.strip()
        if not sep or not name:
            raise ConfigError(f"--fgo {item!r}: expected key=value")
        if name not in hints:
            raise ConfigError(
                f"--fgo {name}: no such factor-graph setting; see FgoConfig in coplane/fgo/config.py"
            )
        out[name] = _parse(name, text.strip(), hints[name])
    return out


def apply_fgo_overrides(cfg: FgoConfig, changes: dict[str, object]) -> FgoConfig:
    """`cfg` with `changes`; a value FgoConfig refuses raises ConfigError with its reason."""
    try:
        return dataclasses.replace(cfg, **changes)  # type: ignore[arg-type]
    except ValueError as exc:
        raise ConfigError(f"--fgo: {exc}") from None
