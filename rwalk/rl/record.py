"""A run's record: config.json, its resolved configs, written and read back as data.

``write_record`` stores a training (``rwalk.rl.config.Training``, or the TorchRL
trainer's ``TorchRLTraining``) with a schema version and the trainer that ran it;
``read_record`` reads it back as data: at most MAX_CONFIG_BYTES, parsed as JSON,
every field checked against its config (``rwalk.configdata``), never evaluated.
Records of schema 1 (the run's flags under ``"args"``) are read through the one
migration, ``rwalk.rl.legacy.from_flags``. Every refusal is a ``ConfigError`` that
names the file and the field.

A record also lists the machines the run trained on (``"machines"``,
``rwalk.machine.describe``): a run repeats bit for bit on one machine, not across CPUs
that round differently, and a resume on another machine adds it to the list.
"""

from __future__ import annotations

import json
import typing
from pathlib import Path
from typing import Any

from rwalk.configdata import RecordError, decode, encode, shown
from rwalk.machine import describe
from rwalk.machine import shown as shown_machine
from rwalk.rl.config import PREDATING, Preset, Training
from rwalk.tasks.registry import get_task

#: The layout of config.json this version writes.
SCHEMA = 2
#: Largest config.json read (a run's is a few KB).
MAX_CONFIG_BYTES = 1 << 20
#: The trainer a record without the key was written by (rwalk-train before the key).
DEFAULT_TRAINER = "rsl_rl"


class ConfigError(ValueError):
    """A run's config.json that cannot be read as its configs; the message names the file
    and the field."""


def record_of(training: Any, trainer: str = DEFAULT_TRAINER,
              machines: list[dict[str, str]] | None = None) -> dict[str, Any]:  # fmt: skip
    """The JSON object of ``training``'s record (with ``machines``, where given)."""
    extra = {"machines": machines} if machines else {}
    return {"schema": SCHEMA, "trainer": trainer, **encode(training), **extra}


def write_record(path: Path, training: Any, trainer: str = DEFAULT_TRAINER,
                 resumed: Path | None = None) -> str | None:  # fmt: skip
    """Write ``training``'s record to ``path``, atomically, with the machines it trained
    on: this one, after those of the record ``resumed`` (the config.json of the run a
    resume goes on from; None: a new run).

    Returns:
        A note when this machine is not the one the resumed run last trained on (the run
        will not repeat bit for bit from here), else None.
    """
    from rwalk.rl.checkpoints import atomic_write_text

    machines = read_machines(resumed) if resumed is not None and Path(resumed).is_file() else []
    here, note = describe(), None
    if machines[-1:] != [here]:
        if machines:
            note = (f"this run trained on another machine or library version "
                    f"({shown_machine(machines[-1])}) and goes on on this one "
                    f"({shown_machine(here)}): from here it does not repeat bit for bit; "
                    f"config.json lists both")  # fmt: skip
        machines.append(here)
    atomic_write_text(Path(path), json.dumps(record_of(training, trainer, machines), indent=2))
    return note


def _machines(value: Any, name: str) -> list[dict[str, str]]:
    """A record's ``"machines"`` value, checked: a list of objects of strings."""
    if not isinstance(value, list) or not all(
        isinstance(m, dict) and all(isinstance(k, str) and isinstance(v, str)
                                    for k, v in m.items()) for m in value):  # fmt: skip
        raise ConfigError(f'{name}: "machines" must be a list of objects of strings, got '
                          f"{shown(value)}")  # fmt: skip
    return value


def read_machines(path: Path) -> list[dict[str, str]]:
    """The machines a run's config.json (``path``) lists ([] for a record written before
    the list).

    Raises:
        FileNotFoundError, ConfigError: naming the file.
    """
    saved = read_json(path)
    if not isinstance(saved, dict):
        raise ConfigError(f"{str(path)!r} is not an object of a run's configs")
    return _machines(saved.get("machines", []), repr(str(path)))


def decode_training(cls: type, data: Any, where: str = "") -> Any:
    """A ``cls`` (``Training`` or a trainer's like it) from a record's JSON object: its
    preset names the task, whose config class the env is read as.

    Raises:
        RecordError: naming the field.
    """
    if not isinstance(data, dict):
        raise RecordError(f"{where or 'the record'} must be an object, got {shown(data)}")
    hints = typing.get_type_hints(cls)
    unknown = [key for key in data if key not in hints]
    if unknown:
        raise RecordError(f"unknown key {shown(unknown[0])} (known: {', '.join(hints)})")
    if "env" not in data:
        raise RecordError("the record has no env")
    preset = decode(Preset, data.get("preset", {}), "preset")
    values = {key: decode(hints[key], value, key) for key, value in data.items() if key != "env"}
    values["env"] = decode(get_task(preset.task).config_type, data["env"], "env")
    try:
        return cls(**values)
    except (ValueError, TypeError) as error:
        raise RecordError(str(error)) from None


def read_json(path: Path, limit: int = MAX_CONFIG_BYTES) -> Any:
    """The JSON value of the file ``path``, read only up to ``limit`` bytes.

    Raises:
        FileNotFoundError: naming the file.
        ConfigError: naming the file: unreadable, too large, or not JSON.
    """
    path = Path(path)
    try:
        with path.open("rb") as file:
            data = file.read(limit + 1)
    except FileNotFoundError:
        raise FileNotFoundError(f"{str(path)!r} not found") from None
    except OSError as error:
        raise ConfigError(f"{str(path)!r} cannot be read ({error.strerror})") from None
    if len(data) > limit:
        raise ConfigError(f"{str(path)!r} is larger than {limit} bytes")
    try:
        return json.loads(data)
    except (ValueError, RecursionError) as error:
        raise ConfigError(f"{str(path)!r} is not JSON ({str(error)[:120]})") from None


def read_record(path: Path, trainer: str = DEFAULT_TRAINER, cls: type = Training) -> Any:
    """The training a run's config.json (``path``) records, as data (a schema-1 record
    through the migration ``rwalk.rl.legacy.from_flags``).

    Args:
        trainer: the trainer the run must be of ("rsl_rl": rwalk-train, "torchrl").
        cls: the training class of that trainer.

    Raises:
        FileNotFoundError: naming the file.
        ConfigError: naming the file and what is wrong (size, JSON, another trainer's
            run, an unknown schema, an unknown key or a bad field).
    """
    saved = read_json(path)
    name = repr(str(path))
    if not isinstance(saved, dict):
        raise ConfigError(f"{name} is not an object of a run's configs")
    written_by = saved.get("trainer", DEFAULT_TRAINER)
    if written_by != trainer:
        shown_by = written_by if isinstance(written_by, str) and len(written_by) <= 32 else "?"
        raise ConfigError(f"{name} is the config of a run of the {shown_by!r} trainer, not of "
                          f"{trainer!r}")  # fmt: skip
    schema = saved.get("schema", 1)
    try:
        if schema == 1:
            from rwalk.rl.legacy import migrate

            if not isinstance(saved.get("args"), dict):
                raise ConfigError(f'{name} has no object "args" of a run\'s flags')
            return migrate(saved["args"], trainer)
        if schema != SCHEMA:
            raise ConfigError(f"{name} has schema {shown(schema)}; this rwalk reads schemas 1 "
                              f"and {SCHEMA} (a newer rwalk wrote it?)")  # fmt: skip
        _machines(saved.get("machines", []), name)
        body = {k: v for k, v in saved.items() if k not in ("schema", "trainer", "machines")}
        if cls is Training and isinstance(body.get("train"), dict):
            body["train"] = PREDATING | body["train"]
        if isinstance(body.get("preset"), dict):  # a run before --recipe trained plain
            body["preset"] = {"recipe": "plain"} | body["preset"]
        return decode_training(cls, body)
    except ConfigError:
        raise
    except (ValueError, TypeError) as error:
        where = "args: " if schema == 1 else ""
        raise ConfigError(f"{name}: {where}{error}") from None


def load_saved_args(path: Path, cls: type | None = None, trainer: str = DEFAULT_TRAINER) -> Any:
    """The record of a run's config.json (older name of ``read_record``; ``cls``: the
    training class, default that of rwalk-train)."""
    return read_record(path, trainer, cls or Training)
