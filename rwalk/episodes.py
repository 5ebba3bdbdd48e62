"""One auto-reset and one set of episode statistics for every consumer.

``step(core, action)`` steps the core and, for the envs whose episodes ended,
returns their statistics (read before the reset) and resets them. The rsl-rl
adapter and ``rwalk-play``'s evaluation both go through it, so an episode's
return, length, fall, speed and velocity error mean the same everywhere.
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor

from rwalk.core import Core, StepResult


class EpisodeEnd(NamedTuple):
    """The episodes that ended in one step."""

    ids: Tensor
    """Their envs, sorted. Shape: (M,)."""
    stats: dict[str, Tensor]
    """Per episode, each (M,): ``Core.episode_log``'s ``"sum/<term>"``, ``"length"``,
    ``"forward_velocity"``, ``"target_velocity"`` and ``"velocity_error"`` (mean
    |v_x - v*| per step), plus ``"return"`` (the sum of the term sums),
    ``"terminated"`` (fell or diverged) and ``"diverged"``."""


def step(
    core: Core, action: Tensor, auto_reset: bool = True
) -> tuple[StepResult, EpisodeEnd | None]:
    """``core.step(action)``, then the statistics of the episodes that ended and,
    with ``auto_reset``, their resets (rsl-rl's convention: the returned result
    still shows the last step of the ended episodes, the core the new ones).

    Returns:
        The step's result, and None where no episode ended.
    """
    result = core.step(action)
    done = result.terminated | result.truncated
    if not bool(done.any()):
        return result, None
    ids = done.nonzero().squeeze(-1)
    stats = core.episode_log(ids)
    sums = [value for key, value in stats.items() if key.startswith("sum/")]
    stats["return"] = sum(sums, torch.zeros_like(stats["length"]))
    stats["terminated"] = result.terminated[ids]
    stats["diverged"] = result.diverged[ids]
    if auto_reset:
        core.reset(ids)
    return result, EpisodeEnd(ids, stats)
