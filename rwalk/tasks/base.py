"""What a task declares, and the pieces every task shares.

A task is one small module over ``rwalk.core.Core``: a ``Task`` subclass that
says how an action becomes servo targets (``act``), which named observation
pieces make its spec observation and which extra pieces the views offer
(``pieces``), its reward terms (``reward_terms``, each a ``RewardTerm``), and
what it keeps per env across a reset (``reset``). The core owns everything
else: the simulation, seeding, resets and settling, termination and episode
bookkeeping. Specs, ``reward_terms`` keys, ``info["reward_components"]``,
TensorBoard tags, rsl-rl observation groups and the docs' tables are all built
from these declarations.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, ClassVar, NamedTuple

import numpy as np
import torch
from torch import Tensor

from rwalk import rng
from rwalk.config import EnvConfig
from rwalk.constants import OBS_DIM, OBS_FOOT_POS, OBS_POS, OBS_QUAT
from rwalk.randomization import PHYSICS_PARAMS
from rwalk.rewards import RewardTerm, spec_terms

if TYPE_CHECKING:
    from rwalk.core import Core


class ObsPiece(NamedTuple):
    """A named block of observation values."""

    size: int
    read: Callable[[Task], Tensor]
    """The block for every env, float64. Shape: (N, size)."""
    doc: str


#: Ground samples around each foot for the privileged critic, in world axes: under the
#: foot, and 3 cm ahead, behind, left and right of it. Metres.
HEIGHT_OFFSETS = ((0.0, 0.0), (0.03, 0.0), (-0.03, 0.0), (0.0, 0.03), (0.0, -0.03))
#: Pieces a critic may add to the policy's: the world the actor cannot see.
PRIVILEGED_PIECES = ("physics", "heights")


def foot_clearances(core: Core) -> Tensor:
    """Height of each foot above the ground at HEIGHT_OFFSETS around it, foot-major.

    The feet's world positions come from the torso's position and orientation and the
    feet's positions in the torso frame (the observation's sensors), with elementwise
    products and sums only. Shape: (N, 4 * len(HEIGHT_OFFSETS)) float64. Metres.
    """
    obs = core.obs
    n = obs.shape[0]
    w, x, y, z = obs[:, OBS_QUAT].unbind(-1)
    rotation = (
        (1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y)),
        (2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x)),
        (2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y)),
    )
    local = obs[:, OBS_FOOT_POS].view(n, 4, 3)
    world = [
        obs[:, OBS_POS.start + i, None]
        + row[0][:, None] * local[..., 0]
        + row[1][:, None] * local[..., 1]
        + row[2][:, None] * local[..., 2]
        for i, row in enumerate(rotation)
    ]  # each (N, 4)
    offsets = torch.tensor(HEIGHT_OFFSETS, dtype=torch.float64)
    ground = core.terrain.heights_at(
        world[0][..., None] + offsets[:, 0], world[1][..., None] + offsets[:, 1]
    )
    return (world[2][..., None] - ground).reshape(n, -1)


#: Pieces every task has. ``sensors`` is the spec's 65-D observation.
COMMON_PIECES: dict[str, ObsPiece] = {
    "sensors": ObsPiece(OBS_DIM, lambda task: task.core.obs,
                        "the spec's 65 values: torso, joints, feet, contacts"),
    "phase": ObsPiece(2, lambda task: task.phase_features(), "sin, cos of 2π x the gait phase"),
    "lateral_offset": ObsPiece(
        1, lambda task: (task.core.obs[:, OBS_POS.start + 1] - task.core.y0).unsqueeze(-1),
        "torso y - y0, the drift the lateral term sees (m)"),
    "command": ObsPiece(
        1, lambda task: task.target.unsqueeze(-1),
        "the episode's target velocity (m/s; config.command_range)"),
    "physics": ObsPiece(
        len(PHYSICS_PARAMS), lambda task: task.core.perturb.normalised_params(),
        "privileged: the env's randomised physics, centred and scaled (rwalk.randomization)"),
    "heights": ObsPiece(
        4 * len(HEIGHT_OFFSETS), lambda task: foot_clearances(task.core),
        "privileged: each foot's height above the ground under it and 3 cm around it (m)"),
}  # fmt: skip
#: Random stream of the per-episode velocity commands (see ``rwalk.rng``).
COMMAND_STREAM = "command"


class Task:
    """Base of every task; a subclass is one task (see the module docstring).

    Args:
        core: the core it runs in (built, not yet reset). A task keeps per-env
            state as tensors of batch size ``core.num_envs``; no Python loop per env.
    """

    name: ClassVar[str]
    """Registry name, e.g. ``"residual_walk"``."""
    config_type: ClassVar[type[EnvConfig]] = EnvConfig
    """The config class the task takes."""
    action_dim: ClassVar[int]
    """Values per env in an action."""
    action_layout: ClassVar[str]
    """What the action's values are, for error messages and docs."""
    observation: ClassVar[tuple[str, ...]] = ("sensors",)
    """Pieces that make the spec observation, in order."""
    single_step: ClassVar[bool] = False
    """Whether a one-env core may step through ``rwalk.single``'s float pipeline
    (which implements this task's step on numpy and floats)."""

    def __init__(self, core: Core) -> None:
        self.core = core
        n = core.num_envs
        self.target = torch.full((n,), core.config.expected_velocity, dtype=torch.float64)
        """Target velocity of each env's episode. Shape: (N,). m/s."""
        self.draws = torch.zeros(n, dtype=torch.long)
        """Commands drawn so far by each env (the counter of its next draw). Shape: (N,)."""

    # ------------------------------------------------------------ declarations
    def pieces(self) -> dict[str, ObsPiece]:
        """Every named observation piece of this task (the views choose from these)."""
        return dict(COMMON_PIECES)

    def extras(self) -> tuple[str, ...]:
        """Pieces the views offer beside the spec observation (``command`` when the
        config draws commands)."""
        commanded = self.core.config.command_range is not None
        return ("phase", "lateral_offset", *(("command",) if commanded else ()))

    def privileged(self) -> tuple[str, ...]:
        """Pieces only a critic sees (PRIVILEGED_PIECES), offered when the config varies
        the world: randomised physics, pushes, noise or terrain levels."""
        cfg = self.core.config
        varied = (cfg.randomization, cfg.pushes, cfg.observation_noise, cfg.terrain_levels)
        return PRIVILEGED_PIECES if any(v is not None for v in varied) else ()

    def reward_terms(self) -> tuple[RewardTerm, ...]:
        """The reward's terms, in the order they are added and reported."""
        return spec_terms(self.core.config.reward_weights)

    @property
    def observation_dim(self) -> int:
        pieces = self.pieces()
        return sum(pieces[name].size for name in self.observation)

    def spec_observation(self) -> Tensor:
        """The spec observation of every env, float64. Shape: (N, observation_dim)."""
        if self.observation == ("sensors",):
            return self.core.obs
        pieces = self.pieces()
        return torch.cat([pieces[name].read(self) for name in self.observation], dim=-1)

    # ------------------------------------------------------------ behaviour
    def seed(self) -> None:
        """Restart the task's own random streams (the core was reseeded)."""
        self.draws.zero_()

    def reset(self, rows: Tensor) -> None:
        """Start the episodes of ``rows``, whose starts were just settled. Shape: (M,)."""
        raise NotImplementedError

    def draw_commands(self, rows: Tensor) -> None:
        """Each env of ``rows`` draws its episode's target velocity from
        ``config.command_range``: env i's k-th from the key (seed + i, "command", k)."""
        low_high = self.core.config.command_range
        if low_high is None:
            return
        u = self.uniform(rows, COMMAND_STREAM, self.draws, 1)[:, 0]
        self.target[rows] = low_high[0] + u * (low_high[1] - low_high[0])

    def uniform(self, rows: Tensor, stream: str, counters: Tensor, n: int) -> Tensor:
        """n uniform [0, 1) numbers per env of ``rows`` from env i's key (seed + i,
        ``stream``, counters[i]); each counter then moves on by one. Shape: (M, n) float64."""
        return rng.uniform_rows(self.core.seed_value, rows, stream, counters, n)

    def act(self, action: Tensor) -> tuple[np.ndarray, Tensor]:
        """Servo targets for the next ``core.decimation`` substeps, and advance the gait.

        Args:
            action: checked and clipped to [-1, 1], float64. Shape: (N, action_dim).

        Returns:
            ctrl: joint targets. Shape: (N, K, 12) float64, C-contiguous.
            swing: the gait's swing flags at the start of the last substep, whose
                sensors the step reports. Shape: (N, 4) bool.
        """
        raise NotImplementedError

    @property
    def v_target(self) -> Tensor | float:
        """Velocity the reward tracks: the gait's (a float), or per env (N,) when the
        config draws commands. m/s."""
        if self.core.config.command_range is None:
            return self.core.config.expected_velocity
        return self.target

    @property
    def phase(self) -> Tensor:
        """Gait phase in [0, 1) at the start of the next step. Shape: (N,)."""
        raise NotImplementedError

    def phase_features(self) -> Tensor:
        """(sin 2πφ, cos 2πφ) of the gait phase. Shape: (N, 2)."""
        raise NotImplementedError

    def state(self) -> dict[str, Tensor]:
        """Per-env tensors to keep when the core is pickled."""
        return {"target": self.target, "draws": self.draws}
