"""Checkpoints as data: atomic writes, loads that can never run code, and run folders.

rsl-rl's ``OnPolicyRunner.load`` unpickles with ``weights_only=False``, so a
crafted ``.pt`` file runs whatever it holds. Every checkpoint here is read with
``torch.load(weights_only=True)`` first, which admits only tensors, numbers,
strings and plain containers, and only then handed to the algorithm.

A run folder holds one training run: its checkpoints ``model_<it>.pt`` (the
state after iteration ``it``, counted from 0), and while a run writes to it, the
lock file ``.rwalk.lock`` holding that process's pid.
"""

from __future__ import annotations

import io
import os
import pickle
import re
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any

import torch

CHECKPOINT_NAME = re.compile(r"model_(\d+)\.pt")
"""rsl-rl's checkpoint names; group 1 is the iteration."""
LOCK_NAME = ".rwalk.lock"
"""The lock file of a run folder; holds the pid of the process writing to it."""
TRAINER = "rsl_rl"
"""The ``"trainer"`` entry of checkpoints that ``rwalk.rl.runner.SafeRunner`` writes
(rwalk-train-torchrl's: "torchrl")."""


class CheckpointError(ValueError):
    """A file that is not a loadable checkpoint (truncated, foreign, or unsafe)."""


class RunSetupError(RuntimeError):
    """A training run that cannot start as asked (folder in use or holding another run,
    or nothing left to train); the message says why and what to pass instead."""


def atomic_write(path: str | os.PathLike[str], write: Callable[[IO[bytes]], None]) -> Path:
    """Write a file so that it is either absent, the old one, or complete.

    ``write`` fills a temporary file in the same folder; it is flushed, synced
    and renamed over ``path``. A kill or a full disk leaves no partial file
    under ``path`` (the temporary file is removed on errors).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        os.fchmod(fd, 0o666 & ~_umask())  # mkstemp makes 0600; a plain write obeys the umask
        with os.fdopen(fd, "wb") as file:
            write(file)
            file.flush()
            os.fsync(file.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def atomic_write_text(path: str | os.PathLike[str], text: str) -> Path:
    """``atomic_write`` of UTF-8 text."""
    return atomic_write(path, lambda file: file.write(text.encode("utf-8")))


def save_checkpoint(obj: Any, path: str | os.PathLike[str]) -> Path:
    """``torch.save`` through ``atomic_write``."""
    return atomic_write(path, lambda file: torch.save(obj, file))


def load_checkpoint(path: str | os.PathLike[str], data: bytes | None = None) -> dict[str, Any]:
    """Read a checkpoint as data (``weights_only=True``); ``data``: the file's bytes, read
    elsewhere (by rank 0 of a distributed run), which ``path`` then only names.

    Raises:
        FileNotFoundError: naming the path.
        CheckpointError: naming the path, if the file is truncated, not a
            checkpoint, or holds anything but tensors and plain values.
    """
    path = Path(path)
    if data is None and not path.is_file():
        raise FileNotFoundError(f"checkpoint {str(path)!r} not found")
    try:
        source = path if data is None else io.BytesIO(data)
        loaded = torch.load(source, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as error:
        # torch's message suggests weights_only=False; name only what was refused.
        lines = [line.strip() for line in str(error).splitlines() if "GLOBAL" in line]
        raise CheckpointError(
            f"checkpoint {str(path)!r} was refused: it holds objects other than tensors and "
            f"plain values, so loading it could run code ({' '.join(lines) or error})"
        ) from None
    except Exception as error:  # truncated zip, not a torch file, ...
        raise CheckpointError(
            f"checkpoint {str(path)!r} cannot be read ({type(error).__name__}: {error})"
        ) from None
    if not isinstance(loaded, dict):
        raise CheckpointError(
            f"checkpoint {str(path)!r} holds a {type(loaded).__name__}, not a dict of states"
        )
    return loaded


def check_rsl_rl(loaded: dict[str, Any], path: str | os.PathLike[str]) -> dict[str, Any]:
    """``loaded`` (from ``load_checkpoint(path)``) if it is an rsl-rl save from rwalk-train.

    Raises:
        CheckpointError: naming the path, if another trainer wrote it or it lacks ``"iter"``.
    """
    trainer = loaded.get("trainer", TRAINER)  # saves from before the key are rsl-rl's
    if trainer != TRAINER:
        raise CheckpointError(
            f"checkpoint {str(path)!r} was written by the {trainer} trainer, not by rsl-rl "
            "(rwalk-train)"
        )
    missing = [key for key in ("iter", "actor_state_dict") if key not in loaded]
    if missing:
        raise CheckpointError(f"checkpoint {str(path)!r} lacks {missing}: not an rsl-rl save")
    return loaded


def checkpoint_files(folder: str | os.PathLike[str]) -> list[tuple[int, Path]]:
    """The ``model_<it>.pt`` files in ``folder`` as (iteration, path), oldest first.

    Temporary files of unfinished writes (``.model_3.pt.x1y2.tmp``) are not checkpoints.
    """
    found = []
    for path in Path(folder).glob("model_*.pt"):
        match = CHECKPOINT_NAME.fullmatch(path.name)
        if match and path.is_file():
            found.append((int(match.group(1)), path))
    return sorted(found)


def newest_checkpoint(
    folder: str | os.PathLike[str], report: Callable[[str], None] = print
) -> tuple[Path, dict[str, Any]]:
    """The checkpoint of ``folder`` with the highest iteration that loads, and its contents.

    Each newer file that does not load (a truncated ``model_9.pt``, ...) is
    skipped, and ``report`` is told which and why.

    Raises:
        FileNotFoundError: naming the folder, if it holds no ``model_<it>.pt``.
        CheckpointError: naming the folder and each file's problem, if none loads.
    """
    folder = Path(folder)
    candidates = checkpoint_files(folder)
    if not candidates:
        raise FileNotFoundError(f"no checkpoint model_<iteration>.pt in {str(folder)!r}")
    problems = []
    for _, path in reversed(candidates):
        try:
            return path, check_rsl_rl(load_checkpoint(path), path)
        except CheckpointError as error:
            report(f"skipped {path.name}: {error}")
            problems.append(str(error))
    raise CheckpointError(f"no checkpoint in {str(folder)!r} loads: " + "; ".join(problems))


def _lock_holder(lock: Path) -> int | None:
    """The pid written in a lock file, or None if it is gone or holds no pid."""
    try:
        return int(lock.read_text().strip())
    except (FileNotFoundError, ValueError):
        return None


def _is_running(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # alive, someone else's
        return True
    return True


@contextmanager
def run_lock(
    folder: str | os.PathLike[str], report: Callable[[str], None] = print
) -> Iterator[Path]:
    """Hold ``folder/.rwalk.lock`` (it holds our pid) for the duration of the block.

    The lock file appears complete or not at all (a pid file hard-linked into
    place, which fails if the name exists). A lock whose pid no longer runs (a
    killed run) is taken over, and ``report`` says so. The lock is removed on
    leaving the block if it still holds our pid.

    Raises:
        RunSetupError: naming the folder and the pid, if a running process holds the lock.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    lock = folder / LOCK_NAME
    fd, mine = tempfile.mkstemp(prefix=f"{LOCK_NAME}.", suffix=".tmp", dir=folder)
    try:
        with os.fdopen(fd, "w") as file:
            file.write(f"{os.getpid()}\n")
        for _ in range(3):  # a stale lock is replaced, then taken like a free one
            try:
                os.link(mine, lock)
                break
            except FileExistsError:
                holder = _lock_holder(lock)
                if holder is not None and _is_running(holder):
                    raise RunSetupError(
                        f"{str(folder)!r} is in use by another training (pid {holder} holds "
                        f"{str(lock)!r}); wait for it to end or choose another --log-dir (if "
                        "no training runs there, delete the lock file)"
                    ) from None
                report(f"taking over the stale lock {lock} (pid {holder} is not running)")
                lock.unlink(missing_ok=True)
        else:
            raise RunSetupError(f"could not take the lock {str(lock)!r}: other processes race")
    finally:
        Path(mine).unlink(missing_ok=True)
    try:
        yield lock
    finally:
        if _lock_holder(lock) == os.getpid():
            lock.unlink(missing_ok=True)


def remove_unfinished_writes(folder: str | os.PathLike[str]) -> list[Path]:
    """Delete the temporary files that killed ``atomic_write``s of checkpoints and
    config.json left in ``folder``; call only while holding its ``run_lock``."""
    folder = Path(folder)
    leftovers = [*folder.glob(".model_*.pt.*.tmp"), *folder.glob(".config.json.*.tmp")]
    for path in leftovers:
        path.unlink(missing_ok=True)
    return leftovers


def claim_log_dir(
    log_dir: Path,
    resume: tuple[Path, int] | None,
    resumed_from_folder: bool,
    overwrite: bool,
    report: Callable[[str], None] = print,
) -> None:
    """Make ``log_dir`` this run's own: refuse one that holds another run's checkpoints
    (or, resuming from it, newer ones that would be overwritten) unless ``overwrite``,
    which deletes them; delete temporary files of killed writes. Call while holding its
    lock.

    Args:
        resume: the checkpoint resumed from and its iteration, or None.
        resumed_from_folder: --resume named a folder (its newest checkpoint that loads).

    Raises:
        RunSetupError: naming the folder and the flags that would allow the run.
    """
    resumed, resumed_it = resume if resume else (None, -1)
    own = resumed is not None and resumed.parent.resolve() == log_dir.resolve()
    if own and resumed_from_folder:
        old = []
    else:  # with a file in it, those newer than the file
        old = [path for it, path in checkpoint_files(log_dir) if not own or it > resumed_it]
    if old and overwrite:
        events = [] if own else list(log_dir.glob("events.out.tfevents.*"))
        for path in [*old, *events]:
            path.unlink()
        report(f"--overwrite: deleted {len(old)} checkpoints and {len(events)} event files")
    elif old and own:
        raise RunSetupError(
            f"--resume {resumed} is not the newest checkpoint in {log_dir} (there is "
            f"{old[-1].name}): training on from it would overwrite the newer ones; pass "
            f"--overwrite to delete them, or --resume {log_dir} to continue from the newest"
        )
    elif old:
        raise RunSetupError(
            f"--log-dir {log_dir} already holds another run's checkpoints ({old[0].name} .. "
            f"{old[-1].name}); pass --resume {log_dir} to continue that run, --overwrite to "
            "replace it, or choose another --log-dir"
        )
    for path in remove_unfinished_writes(log_dir):
        report(f"deleted {path.name}, the unfinished write of a killed run")
