"""Command lines from frozen dataclasses: every field a --flag, its metadata["help"] the help.

A dataclass checks its own values in ``__post_init__`` with the ``require_*``
helpers below, whose messages name the flag (``--save-interval must be >= 1,
got 0``); ``parse_dataclass`` turns such a ``ValueError`` into argparse's usage
error (exit status 2).
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable
from dataclasses import MISSING, fields
from pathlib import Path
from typing import Any, TypeVar

T = TypeVar("T")


def flag(name: str) -> str:
    """The command-line flag of a dataclass field: ``save_interval`` -> ``--save-interval``."""
    return "--" + name.replace("_", "-")


def command(module: str) -> str:
    """How the user started this runner, for the usage line: the console script's name
    (``rwalk-train``) when run as one, else ``python -m <module>``."""
    name = Path(sys.argv[0]).name
    return name if name.startswith("rwalk-") else f"python -m {module}"


def build_parser(cls: type, description: str | None, prog: str | None = None):
    """An ``ArgumentParser`` with one flag per field of the dataclass ``cls``.

    Raises:
        TypeError: naming the field, if a field has no ``metadata["help"]``.
    """
    parser = argparse.ArgumentParser(
        prog=prog, description=description, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    for f in fields(cls):
        if not f.metadata.get("help"):
            raise TypeError(f"{cls.__name__}.{f.name} has no metadata['help'] for {flag(f.name)}")
        default = f.default if f.default is not MISSING else f.default_factory()  # type: ignore[misc]
        shown = " ".join(map(str, default)) if isinstance(default, tuple) else repr(default)
        options: dict[str, Any] = {
            "default": default,
            "help": f"{f.metadata['help']} (default: {shown})",
        }
        if isinstance(default, bool):
            options["action"] = argparse.BooleanOptionalAction
        elif isinstance(default, tuple):
            # An empty default names its item type in metadata["item"] (else str).
            kind = f.metadata.get("item") or (type(default[0]) if default else str)
            options.update(type=kind, nargs="+", metavar=kind.__name__.upper())
        else:
            options.update(type=type(default), metavar=type(default).__name__.upper())
        parser.add_argument(flag(f.name), **options)
    return parser


def parse_dataclass(
    cls: type[T], argv: list[str] | None, description: str | None, prog: str | None = None
) -> T:
    """Parse ``argv`` into ``cls``; flags are field names with dashes (--num-envs).

    A ``ValueError`` from ``cls``'s own checks exits like any usage error:
    status 2 and ``<prog>: error: <message>`` on stderr.
    """
    parser = build_parser(cls, description, prog)
    values = vars(parser.parse_args(argv))
    try:
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in values.items()})
    except ValueError as error:
        parser.error(str(error))


def require_at_least(obj: Any, minimum: float, *names: str) -> None:
    """Each named field must be finite and >= minimum (NaN fails too).

    Raises:
        ValueError: ``--<flag> must be >= <minimum>, got <value>``.
    """
    for name in names:
        value = getattr(obj, name)
        if not (value >= minimum and math.isfinite(value)):
            raise ValueError(f"{flag(name)} must be >= {minimum}, got {value}")


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


# argparse types for runners with hand-written parsers: values out of range are usage errors.
def number_type(kind: type, check: Callable[[float], bool], wanted: str):
    """argparse type: ``kind`` values for which ``check`` holds (NaN never does)."""

    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {wanted}, got {text!r}") from None
        if (isinstance(value, float) and not math.isfinite(value)) or not check(value):
            raise argparse.ArgumentTypeError(f"expected {wanted}, got {text!r}")
        return value

    return parse


POSITIVE_INT = number_type(int, lambda v: v >= 1, "a positive integer")
NATURAL_INT = number_type(int, lambda v: v >= 0, "an integer >= 0")
UNIT_FLOAT = number_type(float, lambda v: 0.0 <= v <= 1.0, "a number in [0, 1]")
POSITIVE_FLOAT = number_type(float, lambda v: v > 0.0, "a positive number")
