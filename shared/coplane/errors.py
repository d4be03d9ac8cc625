"""The root of every error coplane raises on purpose.

Library code raises a subclass of `CoplaneError` for anything a user can fix (a bad recording, an
unknown method, an invalid option). The command line catches this one root, prints its message and
exits with its `exit_code`; it does the same for an OS error on a path (coplane.cli). Any other
exception is a bug and keeps its traceback.
"""

from __future__ import annotations

import math
import numbers


class CoplaneError(Exception):
    """A problem with the user's input or environment, with a message that names what and where."""

    exit_code: int = 2


class ConfigError(CoplaneError, ValueError):
    """An invalid option or configuration value (unknown method, rate out of range, ...)."""


class NotFoundError(CoplaneError, KeyError):
    """A named thing the input does not have (a vehicle id, ...); a KeyError for mapping callers."""

    def __str__(self) -> str:  # KeyError's own str() quotes the message
        return str(self.args[0]) if self.args else ""


def require_finite_positive(options: object, names: tuple[str, ...], prefix: str = "") -> None:
    """Raise ValueError naming the first of `options`' fields `names` that is not finite and > 0.

    The option classes check their rates, sigmas and ages alike; `prefix` (e.g. the class name and
    a dot) says whose field it is. NaN fails the test, so it cannot switch a check off silently;
    so does anything that is not a real number (a string or a boolean read from a file)."""
    for name in names:
        value = getattr(options, name)
        number = isinstance(value, numbers.Real) and not isinstance(value, bool)
        if not (number and math.isfinite(value) and value > 0):
            raise ValueError(f"{prefix}{name} must be finite and > 0, got {value!r}")
