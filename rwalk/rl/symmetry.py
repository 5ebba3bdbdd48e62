"""Left-right symmetry augmentation for rsl-rl's PPO (``rwalk-train --symmetry``).

rsl-rl's ``Symmetry`` extension calls ``augment(env, obs, actions)`` on every
minibatch and trains on the originals and their mirrors (Mittal et al., ICRA 2024).
The mirror of each observation group is the concatenation of its pieces' declared
mirrors (``ObsPiece.mirror``), the action's is the task's (``Task.action_mirror``):
see ``rwalk.mirror`` for what the robot's mirror does to each value, the half gait
cycle included.
"""

from __future__ import annotations

import torch
from tensordict import TensorDict
from torch import Tensor

from rwalk.mirror import Mirror


def apply(mirror: Mirror, values: Tensor) -> Tensor:
    """``values`` mirrored along their last dimension. Shape: (..., D) -> (..., D)."""
    index = torch.tensor(mirror.index, dtype=torch.long, device=values.device)
    signs = torch.tensor(mirror.signs, dtype=values.dtype, device=values.device)
    return values[..., index] * signs


def augment(env, obs: TensorDict | None = None, actions: Tensor | None = None):
    """rsl-rl's ``data_augmentation_func``: each batch followed by its mirror.

    Args:
        env: the ``RslRlVecEnv`` (its groups' and its task's mirrors).
        obs: observation groups. Shape: (B, D_group) each; None: not asked for.
        actions: Shape: (B, A); None: not asked for.

    Returns:
        (obs, actions) of batch 2B (originals first), each None where not given.
    """
    if obs is not None:
        groups = list(obs.keys())  # (iterating a TensorDict walks its batch, not its keys)
        mirrored = {group: apply(env.mirror(group), obs[group]) for group in groups}
        obs = torch.cat([obs, TensorDict(mirrored, batch_size=obs.batch_size)], dim=0)
    if actions is not None:
        actions = torch.cat([actions, apply(env.action_mirror(), actions)], dim=0)
    return obs, actions
