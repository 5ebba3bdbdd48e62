"""The configs runners share, as config values: the training's worlds, the evaluation's
episodes and the base-gait check's.

Each is an ``EnvConfig`` (or a function from configs to a config), and each default is
written once: the episode and settle lengths are ``EnvConfig``'s own. A task makes its
own config from these (``Task.training_config``, ``Task.evaluation_config``), so that
an evaluation env acts as the run's policy was trained to (its action, gait and
commands, from the run's record) whatever the task.
"""

from __future__ import annotations

import dataclasses

from rwalk.config import EnvConfig
from rwalk.levels import TerrainLevels
from rwalk.observations import ObservationNoise
from rwalk.perturbations import Pushes
from rwalk.randomization import Randomization
from rwalk.rewards import GaitCosts
from rwalk.tasks import get_task, task_for_config

__all__ = [
    "BASE_GAIT", "BASE_GAIT_SPREAD", "BASE_GAIT_WORLDS", "EVALUATION", "PAD_SPREAD", "ROBUST",
    "SETTLE_POOL_FRACTION", "START_SPREAD", "TRAINING", "base_gait_config", "evaluation_config",
    "evaluation_env", "get_task", "robust_parts", "robust_world", "training_config",
    "training_env",
]  # fmt: skip

#: Half-widths (x, y) of the start spread over the training terrain. Metres.
START_SPREAD = (0.5, 1.2)
#: Half-widths (x, y) of the start spread on a pad of the terrain-levels map (0.8 m x 1 m). Metres.
PAD_SPREAD = (0.1, 0.1)
#: The base-gait measurements' spread (wider in y: unsettled starts, no policy to
#: keep off the terrain's edge within an episode). The documented figures use it.
BASE_GAIT_SPREAD = (0.5, 1.5)

#: Share of a training's envs kept ready as settled starts (``training_env``).
SETTLE_POOL_FRACTION = 0.25
#: A training's episodes in the one rough world: starts perturbed and spread over the
#: terrain, short settles (served from a pool: ``training_env`` sizes it).
TRAINING = EnvConfig(randomize=True, settle_steps=100, settle_reuse=4, position_noise=START_SPREAD)
#: The robust training's world: a terrain-levels map with its curriculum, physics
#: randomisation, pushes and observation noise, each at its defaults; starts on the pads.
ROBUST = dataclasses.replace(
    TRAINING, position_noise=PAD_SPREAD, terrain_levels=TerrainLevels(),
    randomization=Randomization(), pushes=Pushes(), observation_noise=ObservationNoise(),
)  # fmt: skip
#: The spec's evaluation episodes on the rough world (EnvConfig's settle and episode
#: lengths), starts spread over the terrain, nothing randomised.
EVALUATION = EnvConfig(randomize=True, position_noise=START_SPREAD)
#: The base-gait check (docs/base_gait.md, docs/physics.md): starts from standing (no
#: settling), yaw perturbed by ±0.1 rad, spread over the rough terrain.
BASE_GAIT = EnvConfig(settle_steps=0, randomize=True, position_noise=BASE_GAIT_SPREAD,
                      yaw_noise=0.1, tilt_noise=0.0)  # fmt: skip
#: The worlds the base-gait check walks on, by name (docs/base_gait.md, docs/physics.md).
BASE_GAIT_WORLDS = {"flat": "model/world_flat.xml", "rough": "model/world_train.xml"}


def training_env(
    task: str = "residual_walk",
    *,
    num_envs: int,
    robust: bool = True,
    costs: bool = False,
    settle_pool_fraction: float = SETTLE_POOL_FRACTION,
) -> EnvConfig:
    """The training env of ``task`` for ``num_envs`` envs: the ``ROBUST`` world, or the one
    rough world of ``TRAINING``; a pool of ``settle_pool_fraction`` x ``num_envs`` settled
    starts; with ``costs``, the gait costs at their defaults (``rwalk.rewards.GaitCosts``)."""
    base = ROBUST if robust else TRAINING
    pool = max(1, round(settle_pool_fraction * num_envs))
    base = dataclasses.replace(base, settle_pool=pool, costs=GaitCosts() if costs else None)
    return get_task(task).training_config(base)


def evaluation_env(
    trained: EnvConfig, episodes: EnvConfig = EVALUATION, task: str | None = None, **changes
) -> EnvConfig:
    """The evaluation ``episodes`` (default ``EVALUATION``) for a policy of ``task`` (None:
    the task whose config class ``trained`` is) trained in ``trained``: the task's config,
    acting as the policy was trained to (``Task.acting_fields`` from ``trained``), with
    ``changes``."""
    kind = task_for_config(trained) if task is None else get_task(task)
    return kind.evaluation_config(trained, episodes, **changes)


def base_gait_config(world: str, **overrides) -> EnvConfig:
    """The base-gait check (``BASE_GAIT``) on ``world``; on a flat world the starts are
    not spread."""
    spread = (0.0, 0.0) if "flat" in world else BASE_GAIT.position_noise
    config = dataclasses.replace(BASE_GAIT, model_path=world, position_noise=spread)
    return dataclasses.replace(config, **overrides)


# Older names, kept for code written against them.
def training_config(
    task: str = "residual_walk",
    *,
    num_envs: int,
    terrain_scale: float = 1.0,
    settle_steps: int = TRAINING.settle_steps,
    settle_pool_fraction: float = SETTLE_POOL_FRACTION,
    settle_reuse: int = TRAINING.settle_reuse,
    max_episode_steps: int = EnvConfig.max_episode_steps,
    threads: int = 0,
    command_range: tuple[float, float] | None = None,
    start_spread: float = 0.5,
    robust: bool = False,
    levels: TerrainLevels | None = None,
    costs: GaitCosts | None = None,
    gait_action: str = "delta",
) -> EnvConfig:
    """``training_env`` with these fields set (``levels``: the robust world's map;
    ``terrain_scale``: the one rough world's roughness; ``start_spread`` and
    ``gait_action`` where the task's config has them)."""
    env = training_env(task, num_envs=num_envs, robust=robust,
                       settle_pool_fraction=settle_pool_fraction)  # fmt: skip
    world = {"terrain_levels": levels or env.terrain_levels} if robust else {
        "terrain_scale": terrain_scale}  # fmt: skip
    env = dataclasses.replace(
        env, settle_steps=settle_steps, settle_reuse=settle_reuse, num_threads=threads,
        max_episode_steps=max_episode_steps, command_range=command_range, costs=costs, **world,
    )  # fmt: skip
    return get_task(task).configure(env, start_spread=start_spread, gait_action=gait_action)


def evaluation_config(
    task: str = "residual_walk",
    terrain_scale: float = 1.0,
    max_steps: int = EVALUATION.max_episode_steps,
    settle_steps: int = EVALUATION.settle_steps,
    command_range: tuple[float, float] | None = None,
    gait_action: str = "delta",
) -> EnvConfig:
    """``evaluation_env`` for a policy of ``task`` trained at the defaults (with
    ``gait_action`` where the task's config has it)."""
    kind = get_task(task)
    trained = kind.configure(kind.config_type(), gait_action=gait_action)
    return evaluation_env(trained, terrain_scale=terrain_scale, max_episode_steps=max_steps,
                          settle_steps=settle_steps, command_range=command_range)  # fmt: skip


def robust_world() -> dict:
    """The robust world's parts (``ROBUST``'s), as ``EnvConfig`` fields."""
    names = ("terrain_levels", "randomization", "pushes", "observation_noise")
    return {name: getattr(ROBUST, name) for name in names}


robust_parts = robust_world
