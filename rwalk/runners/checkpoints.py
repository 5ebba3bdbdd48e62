"""Checkpoints as data: atomic writes, and loads that can never run code.

rsl-rl's ``OnPolicyRunner.load`` unpickles with ``weights_only=False``, so a
crafted ``.pt`` file runs whatever it holds. Every checkpoint here is read with
``torch.load(weights_only=True)`` first, which admits only tensors, numbers,
strings and plain containers, and only then handed to the algorithm.
"""

from __future__ import annotations

import os
import pickle
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any

import torch
from rsl_rl.runners import OnPolicyRunner


class CheckpointError(ValueError):
    """A file that is not a loadable checkpoint (truncated, foreign, or unsafe)."""


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
        with os.fdopen(fd, "wb") as file:
            write(file)
            file.flush()
            os.fsync(file.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def atomic_write_text(path: str | os.PathLike[str], text: str) -> Path:
    """``atomic_write`` of UTF-8 text."""
    return atomic_write(path, lambda file: file.write(text.encode("utf-8")))


def save_checkpoint(obj: Any, path: str | os.PathLike[str]) -> Path:
    """``torch.save`` through ``atomic_write``."""
    return atomic_write(path, lambda file: torch.save(obj, file))


def load_checkpoint(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Read a checkpoint as data (``weights_only=True``).

    Raises:
        FileNotFoundError: naming the path.
        CheckpointError: naming the path, if the file is truncated, not a
            checkpoint, or holds anything but tensors and plain values.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"checkpoint {str(path)!r} not found")
    try:
        loaded = torch.load(path, map_location="cpu", weights_only=True)
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


class SafeRunner(OnPolicyRunner):
    """rsl-rl's ``OnPolicyRunner`` whose checkpoints are written atomically and read as data."""

    def save(self, path: str, infos: dict | None = None) -> None:
        saved = self.alg.save()
        saved["iter"] = self.current_learning_iteration
        saved["infos"] = infos
        save_checkpoint(saved, path)
        self.logger.save_model(path, self.current_learning_iteration)

    def load(
        self,
        path: str,
        load_cfg: dict | None = None,
        strict: bool = True,
        map_location: str | None = None,
    ) -> dict | None:
        loaded = load_checkpoint(path)
        missing = [key for key in ("iter",) if key not in loaded]
        if missing:
            raise CheckpointError(f"checkpoint {str(path)!r} lacks {missing}: not an rsl-rl save")
        if self.alg.load(loaded, load_cfg, strict):
            self.current_learning_iteration = loaded["iter"]
        return loaded.get("infos")
