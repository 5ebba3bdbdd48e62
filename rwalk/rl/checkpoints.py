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
import zipfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any

import torch

CHECKPOINT_NAME = re.compile(r"(model|torchrl)_(\d+)\.pt")
"""Checkpoint names of both trainers (rwalk-train's model_<it>.pt, rwalk-train-torchrl's
torchrl_<n>.pt); group 1 is the file prefix, group 2 the iteration."""
PREFIXES = {"rsl_rl": "model", "torchrl": "torchrl"}
"""The file prefix of each trainer's checkpoints."""
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
    _make_folder(path.parent)
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


def check_writable(path: str | os.PathLike[str], what: str) -> None:
    """Refuse, before any work, a file that could not be written at ``path``: the path is
    a folder, or its nearest existing folder is a file or not writable.

    Raises:
        ValueError: naming ``what`` (the flag), the path and why.
    """
    path = Path(path)
    folder = path.parent
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    if path.is_dir():
        why = "is a folder"
    elif not folder.is_dir():
        why = f"cannot be written: {str(folder)!r} is not a folder"
    elif not os.access(folder, os.W_OK | os.X_OK):
        why = f"cannot be written: {str(folder)!r} is not writable"
    else:
        return
    raise ValueError(f"{what} {str(path)!r} {why}")


def check_outputs(prog: str, outputs: dict[str, Path | None]) -> None:
    """Before a command's work: exit with one usage line (``rwalk.cli.usage_error``) for
    the first of ``outputs`` (flag -> file, None: not asked for) that could not be
    written (``check_writable``)."""
    from rwalk.cli import usage_error

    for flag, path in outputs.items():
        try:
            if path is not None:
                check_writable(path, flag)
        except ValueError as error:
            usage_error(prog, str(error))


def save_checkpoint(obj: Any, path: str | os.PathLike[str]) -> Path:
    """``torch.save`` through ``atomic_write``."""
    return atomic_write(path, lambda file: torch.save(obj, file))


#: Largest checkpoint read: its file, and all its entries unpacked (a run's is ~1 MB).
MAX_CHECKPOINT_BYTES = 256 << 20
#: Most entries in a checkpoint's archive, and most keys of its top-level dict.
MAX_ENTRIES = 10_000
MAX_KEYS = 64
#: Longest error text of a library quoted in a message.
MAX_QUOTE = 200


def quote(text: object) -> str:
    """``str(text)`` on one line, cut to MAX_QUOTE characters (for error texts of libraries)."""
    text = " ".join(str(text).split())
    return text if len(text) <= MAX_QUOTE else text[: MAX_QUOTE - 3] + "..."


def _check_archive(source: IO[bytes], name: str) -> None:
    """Refuse what torch.save never writes, before unpickling anything: a file that is no
    zip archive, compressed entries, or entries whose unpacked size passes the cap (a
    few KB can deflate to GBs).

    Raises:
        CheckpointError: naming the file and what is wrong.
    """
    try:
        with zipfile.ZipFile(source) as archive:
            entries = archive.infolist()
    except (zipfile.BadZipFile, OSError, EOFError, ValueError) as error:
        raise CheckpointError(
            f"checkpoint {name} cannot be read: not a torch checkpoint (no complete zip "
            f"archive: {quote(error)})"
        ) from None
    if len(entries) > MAX_ENTRIES:
        raise CheckpointError(f"checkpoint {name} has {len(entries)} entries, more than "
                              f"{MAX_ENTRIES}")  # fmt: skip
    if any(entry.compress_type != zipfile.ZIP_STORED for entry in entries):
        raise CheckpointError(
            f"checkpoint {name} holds compressed entries, which torch.save never writes"
        )
    unpacked = sum(entry.file_size for entry in entries)
    if unpacked > MAX_CHECKPOINT_BYTES:
        raise CheckpointError(
            f"checkpoint {name} unpacks to {unpacked} bytes, more than the limit of "
            f"{MAX_CHECKPOINT_BYTES} (rwalk.rl.checkpoints.MAX_CHECKPOINT_BYTES)"
        )


def load_checkpoint(path: str | os.PathLike[str], data: bytes | None = None) -> dict[str, Any]:
    """Read a checkpoint as data (``weights_only=True``); ``data``: the file's bytes, read
    elsewhere (by rank 0 of a distributed run), which ``path`` then only names.

    What it accepts is bounded before anything is unpickled (``_check_archive``: a zip
    archive of stored entries, at most MAX_CHECKPOINT_BYTES unpacked), and nothing
    read from the file is ever formatted into a message.

    Raises:
        FileNotFoundError: naming the path.
        CheckpointError: naming the path, if the file is too large, truncated, not a
            checkpoint, or holds anything but tensors and plain values.
    """
    path = Path(path)
    name = repr(str(path))
    if data is None and not path.is_file():
        raise FileNotFoundError(f"checkpoint {name} not found")
    size = path.stat().st_size if data is None else len(data)
    if size > MAX_CHECKPOINT_BYTES:
        raise CheckpointError(f"checkpoint {name} has {size} bytes, more than the limit of "
                              f"{MAX_CHECKPOINT_BYTES}")  # fmt: skip
    try:
        if data is None:
            with path.open("rb") as file:
                _check_archive(file, name)
            # From the path, memory-mapped: torch reads only the records it needs, which
            # pays for the archive check (rwalk.bench.checkpoints measures both).
            loaded = torch.load(path, map_location="cpu", weights_only=True, mmap=True)
        else:
            source = io.BytesIO(data)
            _check_archive(source, name)
            source.seek(0)
            loaded = torch.load(source, map_location="cpu", weights_only=True)
    except CheckpointError:
        raise
    except pickle.UnpicklingError as error:
        # torch's message suggests weights_only=False; name only what was refused.
        lines = [line.strip() for line in str(error).splitlines() if "GLOBAL" in line]
        raise CheckpointError(
            f"checkpoint {name} was refused: it holds objects other than tensors and plain "
            f"values, so loading it could run code ({quote(' '.join(lines) or error)})"
        ) from None
    except RecursionError:
        raise CheckpointError(
            f"checkpoint {name} is nested too deeply to be a checkpoint"
        ) from None
    except Exception as error:  # truncated zip, not a torch file, ...
        raise CheckpointError(
            f"checkpoint {name} cannot be read ({type(error).__name__}: {quote(error)})"
        ) from None
    if not isinstance(loaded, dict):
        raise CheckpointError(
            f"checkpoint {name} holds a {type(loaded).__name__}, not a dict of states"
        )
    if len(loaded) > MAX_KEYS or not all(isinstance(key, str) for key in loaded):
        raise CheckpointError(f"checkpoint {name} is not a dict of at most {MAX_KEYS} named "
                              "states")  # fmt: skip
    return loaded


def trainer_of(loaded: dict[str, Any]) -> str:
    """The trainer that wrote a loaded checkpoint: its ``"trainer"`` key (a short name), else
    ``"torchrl"`` / ``"rsl_rl"`` from its keys, else ``"unknown"``. Nothing else of the
    file is looked at, so a crafted value is never expanded."""
    trainer = loaded.get("trainer")
    if isinstance(trainer, str) and len(trainer) <= 32 and trainer.isidentifier():
        return trainer
    if trainer is not None:
        return "unknown"
    if {"iteration", "actor"} <= loaded.keys():
        return "torchrl"
    if {"iter", "actor_state_dict"} <= loaded.keys():
        return "rsl_rl"
    return "unknown"


def require_trainer(loaded: dict[str, Any], path, trainer: str, writer: str) -> None:
    """Raise a CheckpointError naming the file and both trainers unless ``trainer`` (shown
    as ``writer``) wrote ``loaded``."""
    found = trainer_of(loaded)
    if found != trainer:
        raise CheckpointError(
            f"checkpoint {str(path)!r} was written by the {found} trainer, not by {writer}"
        )


def checked_iteration(loaded: dict[str, Any], key: str, path: str | os.PathLike[str]) -> int:
    """The iteration a checkpoint holds under ``key``: an integer in [0, 10^9).

    Raises:
        CheckpointError: naming the file and the field, for anything else.
    """
    value = loaded.get(key)
    if not isinstance(value, int) or isinstance(value, bool) or not 0 <= value < 10**9:
        shown = repr(value) if isinstance(value, (int, float)) else type(value).__name__
        raise CheckpointError(
            f"checkpoint {str(path)!r}: {key!r} must be an iteration (an integer >= 0), got "
            f"{quote(shown)}"
        )
    return value


def check_rsl_rl(loaded: dict[str, Any], path: str | os.PathLike[str]) -> dict[str, Any]:
    """``loaded`` (from ``load_checkpoint(path)``) if it is an rsl-rl save from rwalk-train
    (PPO's actor and critic, or a distillation's student and teacher): written by that
    trainer, with an iteration and the model states as dicts of tensors.

    Raises:
        CheckpointError: naming the path and the field.
    """
    require_trainer(loaded, path, TRAINER, "rsl-rl (rwalk-train)")
    model = "student_state_dict" if "student_state_dict" in loaded else "actor_state_dict"
    missing = [key for key in ("iter", model) if key not in loaded]
    if missing:
        raise CheckpointError(f"checkpoint {str(path)!r} lacks {missing}: not an rsl-rl save")
    checked_iteration(loaded, "iter", path)
    models = [key for key in loaded if key.endswith("_state_dict") and "optimizer" not in key]
    for key in models:
        value = loaded[key]
        if not isinstance(value, dict) or not all(
            isinstance(k, str) and isinstance(v, torch.Tensor) for k, v in value.items()
        ):
            raise CheckpointError(
                f"checkpoint {str(path)!r}: {key!r} must be a dict of named tensors"
            )
        for name, tensor in value.items():
            if tensor.is_floating_point() and not bool(torch.isfinite(tensor).all()):
                raise CheckpointError(f"checkpoint {str(path)!r}: {key}[{quote(name)!r}] holds "
                                      "non-finite values (a diverged run?)")  # fmt: skip
    return loaded


def checkpoint_files(
    folder: str | os.PathLike[str], trainer: str | None = None
) -> list[tuple[int, Path]]:
    """The checkpoints in ``folder`` as (iteration, path), oldest first: those of
    ``trainer`` ("rsl_rl": model_<it>.pt, "torchrl": torchrl_<n>.pt), or of both (None).

    Temporary files of unfinished writes (``.model_3.pt.x1y2.tmp``) are not checkpoints.
    """
    prefixes = set(PREFIXES.values()) if trainer is None else {PREFIXES[trainer]}
    found = []
    for path in Path(folder).glob("*_*.pt"):
        match = CHECKPOINT_NAME.fullmatch(path.name)
        if match and match.group(1) in prefixes and path.is_file():
            found.append((int(match.group(2)), path))
    return sorted(found)


#: The policy entries averaged by ``average_policy``: the networks' weights; the observation
#: normaliser's running statistics (``obs_normalizer.*``) are the newest checkpoint's.
AVERAGED_PREFIXES = ("mlp.", "rnn.", "distribution.")


def average_policy(paths: list[Path]) -> dict[str, Any]:
    """The newest of ``paths`` (rsl-rl saves of one run) with its policy's weights (a
    distilled student's, else PPO's actor) replaced by their mean over ``paths``: weight
    averaging after the fact (SWA, Izmailov et al. 2018, arXiv 1803.05407). The
    normaliser's statistics, the critic or teacher and the optimizer are the newest's;
    ``"averaged"`` lists the iterations. Each mean is summed in float64 in the order of
    the iterations and rounded once to the weights' dtype: the same bits on every CPU.

    Raises:
        FileNotFoundError, CheckpointError: naming the file: fewer than two, one that
            is not an rsl-rl save, an iteration twice, or a policy of other entries or
            shapes than the newest's.
    """
    loaded = []
    for path in paths:
        state = check_rsl_rl(load_checkpoint(path), path)  # its "iter" checked
        loaded.append((state["iter"], path, state))
    loaded.sort(key=lambda item: item[0])
    if len(loaded) < 2:
        raise CheckpointError(f"averaging needs two checkpoints or more, got {len(loaded)}")
    iterations = [it for it, _, _ in loaded]
    twice = next((it for it in iterations if iterations.count(it) > 1), None)
    if twice is not None:
        raise CheckpointError(f"two checkpoints hold iteration {twice}: of two runs?")
    *_, (_, newest_path, newest) = loaded
    key = "student_state_dict" if "student_state_dict" in newest else "actor_state_dict"
    policy = newest[key]
    shapes = {name: tuple(t.shape) for name, t in policy.items()}
    for _, path, state in loaded:
        if {name: tuple(t.shape) for name, t in (state.get(key) or {}).items()} != shapes:
            raise CheckpointError(
                f"checkpoint {str(path)!r}: its {key!r} has other entries or shapes than "
                f"{str(newest_path)!r}'s: not the same policy"
            )
    averaged = dict(policy)
    for name, tensor in policy.items():
        if name.startswith(AVERAGED_PREFIXES) and tensor.is_floating_point():
            total = torch.zeros(tensor.shape, dtype=torch.float64)
            for _, _, state in loaded:
                total += state[key][name].double()
            averaged[name] = (total / len(loaded)).to(tensor.dtype)
    return {**newest, key: averaged, "averaged": iterations}


def newest_checkpoint(
    folder: str | os.PathLike[str],
    report: Callable[[str], None] = print,
    trainer: str = TRAINER,
    check: Callable[[dict[str, Any], Path], dict[str, Any]] | None = None,
) -> tuple[Path, dict[str, Any]]:
    """The checkpoint of ``trainer`` in ``folder`` with the highest iteration that loads and
    passes ``check`` (default: ``check_rsl_rl``), and its contents.

    Each newer file that does not load (a truncated ``model_9.pt``, ...) is
    skipped, and ``report`` is told which and why.

    Raises:
        FileNotFoundError: naming the folder, if it holds no checkpoint of the trainer.
        CheckpointError: naming the folder and each file's problem, if none loads.
    """
    folder = Path(folder)
    check = check or check_rsl_rl
    candidates = checkpoint_files(folder, trainer)
    if not candidates:
        prefix = PREFIXES[trainer]
        raise FileNotFoundError(f"no checkpoint {prefix}_<iteration>.pt in {str(folder)!r}")
    problems = []
    for _, path in reversed(candidates):
        try:
            return path, check(load_checkpoint(path), path)
        except CheckpointError as error:
            report(f"skipped {path.name}: {error}")
            problems.append(str(error))
    raise CheckpointError(f"no checkpoint in {str(folder)!r} loads: " + "; ".join(problems))


#: Largest pid a lock file may name (Linux's pid_max is at most 2^22).
MAX_PID = 1 << 22


def _lock_holder(lock: Path) -> int | None:
    """The pid written in a lock file, or None if it is gone or holds no valid pid (a
    number in [1, MAX_PID]: 0, -1 and huge numbers name no single process)."""
    try:
        with lock.open("rb") as file:
            pid = int(file.read(32).strip())
    except (FileNotFoundError, ValueError):
        return None
    return pid if 1 <= pid <= MAX_PID else None


def _is_running(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # alive, someone else's
        return True
    return True


def _make_folder(folder: Path) -> None:
    """Create a run folder (and its parents).

    Raises:
        RunSetupError: naming the path, if it (or a parent) is not a folder.
    """
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError):
        raise RunSetupError(
            f"--log-dir {str(folder)!r} is not a folder (a file is in the way)"
        ) from None


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
    _make_folder(folder)
    lock = folder / LOCK_NAME
    if lock.is_symlink() or (lock.exists() and not lock.is_file()):
        raise RunSetupError(
            f"the lock {str(lock)!r} is not a file (a folder or a link is in the way); "
            "remove it if no training runs there"
        )
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
    patterns = [f".{prefix}_*.pt.*.tmp" for prefix in PREFIXES.values()] + [".config.json.*.tmp"]
    leftovers = [path for pattern in patterns for path in folder.glob(pattern)]
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
