"""Command lines from frozen config dataclasses: every field a --flag, its docstring the help.

The configs are the source of truth: ``combine`` makes one flat dataclass of
the fields of several configs (a runner's ``Args``: one flag per field, the
same names), and each config is rebuilt from it (``args.train``, ...). A
config checks its own values in ``__post_init__`` with the ``require_*``
helpers below, whose messages name the flag (``--save-interval must be >= 1,
got 0``); ``parse_dataclass`` turns such a ``ValueError`` into argparse's usage
error (exit status 2).
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import functools
import inspect
import itertools
import math
import sys
import textwrap
from collections.abc import Callable
from dataclasses import MISSING, fields
from functools import cache
from pathlib import Path
from typing import Any, TypeVar

T = TypeVar("T")


def flag(name: str) -> str:
    """The command-line flag of a dataclass field: ``save_interval`` -> ``--save-interval``."""
    return "--" + name.replace("_", "-")


def command(module: str) -> str:
    """How the user started this runner, for the usage line: the console script's name
    (``rwalk-train``) when run as one, else ``python -m <module>``."""
    name = Path(sys.argv[0]).name if sys.argv and sys.argv[0] else ""
    return name if name.startswith("rwalk-") else f"python -m {module}"


@cache
def field_docs(cls: type) -> dict[str, str]:
    """The docstring under each field of a dataclass (and of its dataclass bases), joined
    into one line; fields without one are absent."""
    docs: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        try:
            source = textwrap.dedent(inspect.getsource(klass))
        except (OSError, TypeError):
            continue
        body = ast.parse(source).body
        if not body or not isinstance(body[0], ast.ClassDef):
            continue
        statements = body[0].body
        for node, after in itertools.pairwise(statements):
            doc = getattr(after, "value", None)
            if (
                isinstance(node, ast.AnnAssign)
                and isinstance(node.target, ast.Name)
                and isinstance(after, ast.Expr)
                and isinstance(doc, ast.Constant)
                and isinstance(doc.value, str)
            ):
                docs[node.target.id] = " ".join(doc.value.split())
    return docs


def field_help(cls: type, f: dataclasses.Field) -> str | None:
    """A field's help: its ``metadata["help"]``, else its docstring."""
    return f.metadata.get("help") or field_docs(cls).get(f.name)


def default_of(f: dataclasses.Field) -> Any:
    return f.default if f.default is not MISSING else f.default_factory()  # type: ignore[misc]


def combine(
    name: str,
    parts: dict[str, type],
    defaults: dict[str, Any] | None = None,
    exclude: tuple[str, ...] = (),
    doc: str | None = None,
    namespace: dict[str, Any] | None = None,
) -> type:
    """One frozen dataclass with every field of the config dataclasses ``parts`` (but
    ``exclude``), in order, with their help: a command line of one flag per field.

    An instance checks its values by building each part (whose ``__post_init__``
    checks them, naming the flag) and offers each part as the attribute of its key
    (``args.train``). ``defaults`` overrides fields' defaults (a runner's own);
    ``namespace`` adds methods, and a method ``check`` runs after the parts' checks
    (checks across parts).

    Raises:
        TypeError: if two parts share a field name.
    """
    defaults = defaults or {}
    owners: dict[str, str] = {}
    specs = []
    for key, part in parts.items():
        for f in fields(part):
            if f.name in exclude:
                continue
            if f.name in owners:
                raise TypeError(f"{part.__name__} and {owners[f.name]} both have {f.name!r}")
            owners[f.name] = key
            default = defaults.get(f.name, default_of(f))
            metadata = dict(f.metadata) | {"help": field_help(part, f) or ""}
            specs.append((f.name, f.type, dataclasses.field(default=default, metadata=metadata)))

    def part_of(key: str) -> property:
        cls = parts[key]

        def build(self):
            values = {f: getattr(self, f) for f, owner in owners.items() if owner == key}
            return cls(**values)

        return property(build, doc=f"The {cls.__name__} these flags make.")

    def post_init(self) -> None:
        for key in parts:
            getattr(self, key)  # each part checks its own fields
        extra = getattr(self, "check", None)
        if extra is not None:
            extra()

    methods = {key: part_of(key) for key in parts} | (namespace or {})
    methods |= {"__post_init__": post_init, "__doc__": doc, "parts": dict(parts)}
    return dataclasses.make_dataclass(name, specs, frozen=True, namespace=methods)


def build_parser(cls: type, description: str | None, prog: str | None = None):
    """An ``ArgumentParser`` with one flag per field of the dataclass ``cls``.

    Raises:
        TypeError: naming the field, if a field has neither a docstring nor
            ``metadata["help"]``.
    """
    parser = argparse.ArgumentParser(
        prog=prog, description=description, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    for f in fields(cls):
        text = field_help(cls, f)
        if not text:
            raise TypeError(
                f"{cls.__name__}.{f.name} has no docstring or metadata['help'] for {flag(f.name)}"
            )
        default = default_of(f)
        shown = " ".join(map(str, default)) if isinstance(default, tuple) else repr(default)
        options: dict[str, Any] = {"default": default, "help": f"{text} (default: {shown})"}
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


def explicit_fields(cls: type, argv: list[str] | None) -> frozenset[str]:
    """The fields of ``cls`` that ``argv`` sets itself (not left at their defaults)."""
    parser = build_parser(cls, None)
    for action in parser._actions:
        action.default = argparse.SUPPRESS
    return frozenset(vars(parser.parse_known_args(argv)[0]))


def show_flag(name: str, value: Any) -> str:
    """A flag as typed on a command line: ``--task adaptive_gait``, ``--hidden-dims 64 64``,
    ``--no-robust``."""
    if isinstance(value, bool):
        return flag(name) if value else "--no-" + name.replace("_", "-")
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


#: Largest count a command line takes (int32: episodes, steps, envs).
MAX_COUNT = 2**31 - 1
POSITIVE_INT = number_type(
    int, lambda v: 1 <= v <= MAX_COUNT, f"a positive integer (at most {MAX_COUNT})"
)
NATURAL_INT = number_type(
    int, lambda v: 0 <= v <= MAX_COUNT, f"an integer >= 0 (at most {MAX_COUNT})"
)
SEED = number_type(int, lambda v: 0 <= v < 2**63, "a seed in [0, 2**63)")
UNIT_FLOAT = number_type(float, lambda v: 0.0 <= v <= 1.0, "a number in [0, 1]")
POSITIVE_FLOAT = number_type(float, lambda v: v > 0.0, "a positive number")
SECONDS = number_type(
    float, lambda v: 0.0 < v <= 86_400.0, "a positive number of seconds (at most 86400)"
)


def one_line_errors(module: str):
    """Decorator of a runner's ``main(argv)``: an error a user's input can cause (a bad
    value, too little memory, a file or folder that cannot be written, starts that cannot
    settle) ends the command with one line naming it, ``<prog>: error: ...``, exit status
    2 for values, 1 otherwise; no traceback."""

    def wrap(main: Callable) -> Callable:
        @functools.wraps(main)
        def run(argv: list[str] | None = None):
            from rwalk.starts import SettleError

            try:
                return main(argv)
            except (ValueError, MemoryError, OSError, SettleError) as error:
                text = " ".join(str(error).split()) or type(error).__name__
                print(f"{command(module)}: error: {text[:2000]}", file=sys.stderr)
                raise SystemExit(2 if isinstance(error, ValueError) else 1) from None

        return run

    return wrap


#: Most items of a tuple field, and most characters of a string field, read from a file.
MAX_ITEMS = 64
MAX_TEXT = 4096


def _shown(value: Any) -> str:
    """``value`` for a message, at most 80 characters (a file's value may be huge)."""
    text = repr(value) if isinstance(value, (int, float, bool, str)) else type(value).__name__
    return text if len(text) <= 80 else text[:77] + "..."


def _check_json_value(name: str, kind: str, value: Any) -> Any:
    """``value`` of a field declared ``kind`` ("int", "float", "bool", "str", or a
    "tuple[X, ...]" of those), as read from JSON, converted; ValueError naming the field."""

    def scalar(item_kind: str, item: Any) -> Any:
        if item_kind == "bool" and isinstance(item, bool):
            return item
        if item_kind == "int" and isinstance(item, int) and not isinstance(item, bool):
            return item
        if item_kind == "float" and isinstance(item, (int, float)) and not isinstance(item, bool):
            return float(item)
        if item_kind == "str" and isinstance(item, str) and len(item) <= MAX_TEXT:
            return item
        article = "an" if item_kind == "int" else "a"
        raise ValueError(f"{name} must be {article} {item_kind}, got {_shown(item)}")

    if kind.startswith("tuple["):
        item_kind = kind[len("tuple[") :].split(",")[0].strip()
        if not isinstance(value, (list, tuple)) or len(value) > MAX_ITEMS:
            raise ValueError(f"{name} must be a list of at most {MAX_ITEMS} {item_kind}s, "
                             f"got {_shown(value)}")  # fmt: skip
        return tuple(scalar(item_kind, item) for item in value)
    return scalar(kind, value)


def from_fields(cls: type[T], values: Any, retired: tuple[str, ...] = ()) -> T:
    """An instance of the flat dataclass ``cls`` from a JSON object: each field's value
    checked against its declared type (then by ``cls``'s own checks), missing fields at
    their defaults, ``retired`` keys (flags of older versions) dropped.

    Raises:
        ValueError: naming the first unknown key, a field of the wrong type, or the
            field a check refused (values shown at most 80 characters long).
    """
    if not isinstance(values, dict):
        raise ValueError(f"must be an object of flags, got {_shown(values)}")
    kinds = {f.name: str(f.type) for f in fields(cls)}
    unknown = [key for key in values if key not in kinds and key not in retired]
    if unknown:
        raise ValueError(f"unknown key {_shown(str(unknown[0]))} (known: {', '.join(kinds)})")
    checked = {
        key: _check_json_value(flag(key), kinds[key], value)
        for key, value in values.items()
        if key in kinds
    }
    return cls(**checked)
