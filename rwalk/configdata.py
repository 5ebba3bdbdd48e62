"""Configs as data: frozen config dataclasses to JSON and back, every field checked.

``encode`` turns a config (nested dataclasses, tuples, numbers, texts, None) into
JSON values; ``decode`` rebuilds it from JSON read off a file, checking each value
against its field's declared type (``typing.get_type_hints``) before the config's
own ``__post_init__`` checks run. Nothing is evaluated: a file's values are data.
Every error is a ``RecordError`` naming the dotted field (``env.costs.clearance``).
"""

from __future__ import annotations

import dataclasses
import types
import typing
from typing import Any, Union

#: Most items of a tuple, most characters of a text, and most keys of an object read.
MAX_ITEMS = 64
MAX_TEXT = 4096
MAX_KEYS = 256


class RecordError(ValueError):
    """A value read from a file that its config cannot take; the message names the field."""


def encode(value: Any) -> Any:
    """JSON values of a config: a dataclass as an object of its fields, a tuple (or
    NamedTuple) as a list; numbers, texts, bools and None as they are."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: encode(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, (tuple, list)):
        return [encode(item) for item in value]
    return value


def shown(value: Any) -> str:
    """``value`` for a message, at most 80 characters (a file's value may be huge)."""
    text = (
        repr(value)
        if isinstance(value, (int, float, bool, str, type(None)))
        else (type(value).__name__)
    )
    return text if len(text) <= 80 else text[:77] + "..."


def decode(kind: Any, data: Any, where: str) -> Any:
    """The value of type ``kind`` that the JSON value ``data`` stands for.

    Args:
        kind: a field's type: a frozen dataclass, ``X | None``, ``tuple[X, ...]``,
            ``tuple[X, Y]``, a NamedTuple, bool, int, float or str.
        where: the dotted name of the field, for messages.

    Raises:
        RecordError: naming ``where`` (or the nested field) and what is wrong: a wrong
            type, an unknown or missing key, too many items, or a value the config's
            own checks refuse.
    """
    origin = typing.get_origin(kind)
    if origin in (Union, types.UnionType):
        options = typing.get_args(kind)
        if data is None and type(None) in options:
            return None
        (inner,) = [option for option in options if option is not type(None)]
        return decode(inner, data, where)
    if dataclasses.is_dataclass(kind):
        return _dataclass(kind, data, where)
    if origin is tuple or (isinstance(kind, type) and issubclass(kind, tuple)):
        return _tuple(kind, data, where)
    return _scalar(kind, data, where)


def _dataclass(kind: type, data: Any, where: str) -> Any:
    if not isinstance(data, dict) or len(data) > MAX_KEYS:
        raise RecordError(f"{where} must be an object of {kind.__name__}'s fields, got "
                          f"{shown(data)}")  # fmt: skip
    hints = typing.get_type_hints(kind)
    names = [f.name for f in dataclasses.fields(kind) if f.init]
    unknown = [key for key in data if key not in names]
    if unknown:
        raise RecordError(f"{where}: unknown key {shown(unknown[0])} (known: {', '.join(names)})")
    values = {key: decode(hints[key], value, f"{where}.{key}") for key, value in data.items()}
    try:
        return kind(**values)
    except (ValueError, TypeError) as error:
        raise RecordError(f"{where}: {error}") from None


def _tuple(kind: Any, data: Any, where: str) -> tuple:
    if not isinstance(data, list) or len(data) > MAX_ITEMS:
        raise RecordError(f"{where} must be a list of at most {MAX_ITEMS} items, got "
                          f"{shown(data)}")  # fmt: skip
    if isinstance(kind, type) and issubclass(kind, tuple):  # a NamedTuple
        items = tuple(typing.get_type_hints(kind).values())
    else:
        items = typing.get_args(kind)
    if len(items) == 2 and items[1] is Ellipsis:
        items = (items[0],) * len(data)
    if len(items) != len(data):
        raise RecordError(f"{where} must be a list of {len(items)} items, got {len(data)}")
    values = tuple(decode(k, v, where) for k, v in zip(items, data, strict=True))
    return kind(*values) if isinstance(kind, type) and issubclass(kind, tuple) else values


def _scalar(kind: Any, data: Any, where: str) -> Any:
    if kind is bool and isinstance(data, bool):
        return data
    number = isinstance(data, (int, float)) and not isinstance(data, bool)
    if kind is int and number and isinstance(data, int):
        return data
    if kind is float and number:
        return float(data)
    if kind is str and isinstance(data, str) and len(data) <= MAX_TEXT:
        return data
    name = getattr(kind, "__name__", str(kind))
    article = "an" if name == "int" else "a"
    raise RecordError(f"{where} must be {article} {name}, got {shown(data)}")
