"""Input checks of the core: env counts, seeds, env ids and action batches.

Each check raises a ``ValueError`` that names the bad value, before anything runs.
"""

from __future__ import annotations

import os

import numpy as np
import torch
from torch import Tensor

from rwalk.config import MAX_ENVS
from rwalk.rng import SEED_LIMIT


def num_envs(value: object) -> int:
    """``value`` if it is a positive integer.

    Raises:
        ValueError: naming the value.
    """
    if not isinstance(value, int) or isinstance(value, bool) or value < 1:
        raise ValueError(f"num_envs must be a positive integer, got {value!r}")
    if value > MAX_ENVS:
        raise ValueError(f"num_envs must be at most {MAX_ENVS}, got {value!r}")
    return value


def seed(value: object) -> int:
    """A seed in [0, 2^64): ``value``, or one drawn from the OS for None.

    Raises:
        ValueError: naming the value, if it is not an integer in range.
    """
    if value is None:
        return int.from_bytes(os.urandom(8), "little")
    if (
        not isinstance(value, (int, np.integer))
        or isinstance(value, bool)
        or not 0 <= int(value) < SEED_LIMIT
    ):
        raise ValueError(f"seed must be an integer in [0, 2**64) or None, got {value!r}")
    return int(value)


def env_ids(ids: np.ndarray | Tensor | None, count: int) -> np.ndarray:
    """Sorted unique int32 row indices from ids, or from a boolean mask of length ``count``;
    None: every row.

    Raises:
        ValueError: naming the ids, for a wrong dtype, a mask of the wrong shape, ids out
            of range, or ids that are not sorted and unique.
    """
    if ids is None:
        return np.arange(count, dtype=np.int32)
    if isinstance(ids, Tensor):
        ids = ids.detach().cpu().numpy()
    ids = np.asarray(ids)
    if ids.dtype == bool:
        if ids.shape not in ((count,), (count, 1)):
            raise ValueError(f"a boolean env mask must have shape ({count},), got {ids.shape}")
        ids = np.flatnonzero(ids)
    elif not np.issubdtype(ids.dtype, np.integer):
        raise ValueError(
            f"env ids must be integers or a boolean mask, got dtype {ids.dtype} "
            f"({ids.reshape(-1)[:8].tolist()})"
        )
    ids = ids.reshape(-1)
    if ids.size and (ids.min() < 0 or ids.max() >= count):
        raise ValueError(f"env ids must be in [0, {count}), got {ids.tolist()}")
    if ids.size > 1 and not (np.diff(ids) > 0).all():
        raise ValueError(f"env ids must be sorted and unique, got {ids.tolist()}")
    return np.ascontiguousarray(ids.astype(np.int32))


def action(
    value: Tensor | np.ndarray, count: int, action_dim: int, task: str, layout: str
) -> Tensor:
    """An action batch, validated and clipped. Returns float64 (count, action_dim).

    Args:
        task, layout: the task's name and what its action values are (for messages).

    Raises:
        ValueError: naming the action's wrong shape, dtype, device, a non-finite
            value, or that it requires grad.
    """
    if isinstance(value, Tensor):
        if value.requires_grad:
            raise ValueError(
                "action requires grad: pass action.detach() (the simulation is not "
                "differentiable), or act under torch.no_grad()"
            )
        if value.device.type != "cpu":
            raise ValueError(f"action must be on the CPU, got device {value.device}")
    value = torch.as_tensor(value)
    expected = (count, action_dim)
    if tuple(value.shape) != expected:
        raise ValueError(
            f"action must have shape {expected} for task {task!r} ({layout}), got "
            f"{tuple(value.shape)}"
        )
    if value.dtype not in (torch.float32, torch.float64, torch.int32, torch.int64):
        raise ValueError(
            f"action must be float32 or float64 (or integer), got dtype {value.dtype}: "
            "convert it with action.float()"
        )
    value = value.to(torch.float64)
    finite = torch.isfinite(value)
    if not bool(finite.all()):
        env, index = (int(v) for v in (~finite).nonzero()[0])
        raise ValueError(
            f"action has a non-finite value {value[env, index].item()} (env {env}, index {index})"
        )
    return value.clamp(-1.0, 1.0)
