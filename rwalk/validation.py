"""Checks of a config's values whose messages name the command-line flag of the field.

A config checks its own values in ``__post_init__`` with these (``--save-interval
must be >= 1, got 0``); ``rwalk.cli.parse`` turns such a ``ValueError`` into a
one-line usage error.
"""

from __future__ import annotations

import math
from typing import Any

__all__ = [
    "flag", "require_at_least", "require_at_most", "require_choice", "require_in",
    "require_positive", "show_flag",
]  # fmt: skip


class InputError(RuntimeError):
    """A run that cannot go on because of what it was given (not a bug in rwalk): the
    runners end it in one line (``rwalk.cli.one_line_errors``)."""


def flag(name: str) -> str:
    """The command-line flag of a dataclass field: ``save_interval`` -> ``--save-interval``."""
    return "--" + name.replace("_", "-")


def show_flag(name: str, value: Any) -> str:
    """A flag as typed on a command line: ``--task adaptive_gait``, ``--hidden-dims 64 64``,
    ``--no-robust`` (``name`` may be a dotted path: ``--env.settle-steps 2``)."""
    if isinstance(value, bool):
        return flag(name) if value else "--no-" + flag(name)[2:]
    if isinstance(value, (tuple, list)):
        return f"{flag(name)} {' '.join(map(str, value))}".rstrip()
    return f"{flag(name)} {value}"


def require_at_least(obj: Any, minimum: float, *names: str) -> None:
    """Each named field must be finite and >= minimum (NaN fails too).

    Raises:
        ValueError: ``--<flag> must be >= <minimum>, got <value>``.
    """
    for name in names:
        value = getattr(obj, name)
        if not (value >= minimum and math.isfinite(value)):
            raise ValueError(f"{flag(name)} must be >= {minimum}, got {value}")


def require_at_most(obj: Any, maximum: float, *names: str) -> None:
    """Each named field must be <= maximum (after its own lower-bound checks).

    Raises:
        ValueError: ``--<flag> must be at most <maximum>, got <value>``.
    """
    for name in names:
        value = getattr(obj, name)
        if value > maximum:
            shown = maximum if isinstance(maximum, int) else f"{maximum:g}"
            raise ValueError(f"{flag(name)} must be at most {shown}, got {value}")


def require_positive(obj: Any, *names: str, finite: bool = True) -> None:
    """Each named field must be a number > 0 (and finite unless ``finite=False``; NaN fails).

    Raises:
        ValueError: naming the flag and the value.
    """
    for name in names:
        value = getattr(obj, name)
        if not value > 0 or (finite and not math.isfinite(value)):
            what = "a finite number > 0" if finite else "> 0"
            raise ValueError(f"{flag(name)} must be {what}, got {value}")


def require_in(obj: Any, name: str, low: float, high: float, low_open: bool = False) -> None:
    """The named field must lie in [low, high] (or (low, high] with ``low_open``).

    Raises:
        ValueError: naming the flag, the interval and the value.
    """
    value = getattr(obj, name)
    above = value > low if low_open else value >= low
    if not (above and value <= high):
        interval = f"{'(' if low_open else '['}{low:g}, {high:g}]"
        raise ValueError(f"{flag(name)} must be in {interval}, got {value}")


def require_choice(obj: Any, name: str, choices: tuple[str, ...]) -> None:
    """The named field must be one of ``choices``.

    Raises:
        ValueError: naming the flag, the choices and the value.
    """
    value = getattr(obj, name)
    if value not in choices:
        raise ValueError(f"{flag(name)} must be one of {', '.join(choices)}, got {value!r}")
