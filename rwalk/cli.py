"""Command lines from config dataclasses (tyro): every field a flag, its docstring the help.

``parse(Args, argv)``: nested configs give dotted flags (``--env.costs.clearance``),
``aliases`` short names. Every refusal is one line naming the flag as typed, exit 2.
"""

from __future__ import annotations

import contextlib
import dataclasses
import difflib
import functools
import re
import sys
import typing
from collections.abc import Callable
from pathlib import Path
from typing import Any

from rwalk.validation import *  # noqa: F403 (the checks runners once imported from here)
from rwalk.validation import InputError, flag


def command(module: str) -> str:
    """How the user started this runner, for the usage line: the console script's name
    (``rwalk-train``) when run as one, else ``python -m <module>``."""
    name = Path(sys.argv[0]).name if sys.argv and sys.argv[0] else ""
    return name if name.startswith("rwalk-") else f"python -m {module}"


def flags_of(value: Any, prefix: str = "") -> dict[str, str]:
    """Every flag of the config ``value`` -> its field as ``Class.field``: dotted for nested
    configs (``--env.gait.step-height``), top-level for a part typed ``OmitArgPrefixes``."""
    out = {}
    hints = typing.get_type_hints(type(value), include_extras=True)
    for f in dataclasses.fields(value):
        child = getattr(value, f.name)
        if dataclasses.is_dataclass(child):
            flat = "OmitArgPrefixes" in repr(hints[f.name])
            out |= flags_of(child, prefix if flat else f"{prefix}{f.name}.")
        elif child is not None or not any(map(dataclasses.is_dataclass, typing.get_args(
                hints[f.name]))):  # a part left out (None) has no flags  # fmt: skip
            out[flag(prefix + f.name)] = f"{type(value).__name__}.{f.name}"
    return out


def _message(event: Any, known: dict[str, str], typed: dict[str, str]) -> str:
    """One line for tyro's parse-error ``event``, naming the flag as the user typed it."""
    argument = getattr(getattr(getattr(event, "argument", None), "lowered", None),
                       "name_or_flags", None)  # fmt: skip
    name = typed.get(argument[0], argument[0]) if argument else None
    if hasattr(event, "tokens"):
        first = typed.get(event.tokens[0].split("=")[0], event.tokens[0].split("=")[0])
        near = ", ".join(difflib.get_close_matches(first, list(known), 3, 0.6))
        return f"unrecognized argument {first!r}" + (f"; near: {near}" if near else "")
    if hasattr(event, "missing_arguments"):
        return "missing " + ", ".join(a.arg.lowered.metavar or a.arg.lowered.name_or_flags[0]
                                      for a in event.missing_arguments)  # fmt: skip
    if hasattr(event, "choices"):
        return f"{name} must be one of {', '.join(event.choices)}, got {event.value!r}"
    text = re.sub(r"\[/?bold\]", "", str(getattr(event, "message", "")) or type(event).__name__)
    fields = {owner: f for f, owner in known.items() if owner}
    match = re.match(r"(?:[\w.]+: )?([A-Z]\w*\.\w+)\b", text)
    if name is None and match and match.group(1) in fields:
        canonical = fields[match.group(1)]
        return typed.get(canonical, canonical) + text[match.end() :]
    unparsed = re.match(r"(?:no type matching (.+?) could be instantiated from (\[.*?\])|invalid "
                        r"literal for (int)\(\).*: (.*)|could not convert string to (float): (.*))",
                        text)  # a value that does not parse  # fmt: skip
    if name and unparsed:
        kind, value = [g for g in unparsed.groups() if g is not None]
        return f"{name} must be {'an' if kind == 'int' else 'a'} {kind}, got {value}"
    return f"{name}: {text.splitlines()[0]}" if name else " ".join(text.split())


def parse(cls: type, argv: list[str] | None, *, prog: str, description: str | None = None,
          default: Any = None, aliases: dict[str, str] | None = None) -> Any:  # fmt: skip
    """``argv`` (None: ``sys.argv[1:]``) parsed into ``cls``, from ``default``'s values;
    SystemExit 0 after --help, 2 after a one-line error on stderr."""
    import tyro
    import tyro._errors

    aliases = aliases or {}
    given = sys.argv[1:] if argv is None else argv
    typed = {aliases[n]: n for n in (t.partition("=")[0] for t in given) if n in aliases}
    args = [aliases.get(t.partition("=")[0], t.partition("=")[0]) + "".join(t.partition("=")[1:])
            for t in given]  # fmt: skip
    known = (flags_of(default) if default is not None else {}) | dict.fromkeys(aliases, "")
    hooks = getattr(tyro._errors, "on_parse_error", contextlib.nullcontext)  # tyro 1.0's hook
    with hooks(lambda event: usage_error(prog, _message(event, known, typed))):
        return tyro.cli(cls, args=args, prog=prog, description=description, default=default,
                        config=(tyro.conf.AvoidSubcommands,))  # fmt: skip


def usage_error(prog: str, message: str) -> None:
    print(f"{prog}: error: {' '.join(message.split())[:2000]}", file=sys.stderr)  # one line
    raise SystemExit(2)


def one_line_errors(module: str):
    """Decorator of a runner's ``main(argv)``: an error a user's input can cause (a bad value,
    too little memory, a file that cannot be written, starts that cannot settle) ends it in
    one line, ``<prog>: error: ...``, exit status 2 for values, 1 otherwise; no traceback."""

    def wrap(main: Callable) -> Callable:
        @functools.wraps(main)
        def run(argv: list[str] | None = None):
            try:
                return main(argv)
            except (ValueError, MemoryError, OSError, InputError) as error:
                text = " ".join(str(error).split()) or type(error).__name__
                print(f"{command(module)}: error: {text[:2000]}", file=sys.stderr)
                raise SystemExit(2 if isinstance(error, ValueError) else 1) from None

        return run

    return wrap
