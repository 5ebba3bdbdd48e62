"""The configurations runners share: training and evaluation episodes of each task.

One place for the start spread, pooled settling and world, so that the trainer,
the evaluator, the benchmark and the TorchRL trainer run the same episodes.
"""

from __future__ import annotations

import dataclasses

from rwalk.config import EnvConfig
from rwalk.levels import TerrainLevels
from rwalk.observations import ObservationNoise
from rwalk.perturbations import Pushes
from rwalk.randomization import Randomization
from rwalk.tasks import get_task

__all__ = [
    "BASE_GAIT_SPREAD", "PAD_SPREAD", "START_SPREAD", "base_gait_config",
    "evaluation_config", "get_task", "robust_parts", "training_config",
]  # fmt: skip

#: Half-widths (x, y) of the start spread over the training terrain. Metres.
START_SPREAD = (0.5, 1.2)
#: Half-widths (x, y) of the start spread on a pad of the terrain-levels map (0.8 m x 1 m). Metres.
PAD_SPREAD = (0.1, 0.1)
#: The base-gait measurements' spread (wider in y: unsettled starts, no policy to
#: keep off the terrain's edge within 1000 steps). The documented figures use it.
BASE_GAIT_SPREAD = (0.5, 1.5)


def training_config(
    task: str = "residual_walk",
    *,
    num_envs: int,
    terrain_scale: float = 1.0,
    settle_steps: int = 100,
    settle_pool_fraction: float = 0.25,
    settle_reuse: int = 4,
    max_episode_steps: int = 1000,
    threads: int = 0,
    command_range: tuple[float, float] | None = None,
    start_spread: float = 0.5,
    robust: bool = False,
) -> EnvConfig:
    """The training env: pooled settling and starts spread; for adaptive_gait,
    starting parameters spread by ``start_spread`` (see ``AdaptiveGaitConfig.start_spread``).

    ``robust``: on a terrain-levels map with its curriculum, randomised physics,
    pushes and observation noise (``robust_parts``; ``terrain_scale`` is ignored).
    Otherwise one rough world at ``terrain_scale``, starts spread over it.
    """
    kind = get_task(task).config_type
    extra = {"start_spread": start_spread} if "start_spread" in kind.__dataclass_fields__ else {}
    if robust:
        extra |= robust_parts() | {"position_noise": PAD_SPREAD}
    else:
        extra |= {"terrain_scale": terrain_scale, "position_noise": START_SPREAD}
    return kind(
        model_path="model/world_train.xml",
        randomize=True,
        settle_steps=settle_steps,
        settle_pool=max(1, round(settle_pool_fraction * num_envs)),
        settle_reuse=settle_reuse,
        max_episode_steps=max_episode_steps,
        num_threads=threads,
        command_range=command_range,
        **extra,
    )


def robust_parts() -> dict:
    """The robust training's world: a terrain-levels map with its curriculum, randomised
    physics, pushes and observation noise, each at its defaults (``EnvConfig`` fields)."""
    return {
        "terrain_levels": TerrainLevels(),
        "randomization": Randomization(),
        "pushes": Pushes(),
        "observation_noise": ObservationNoise(),
    }


def evaluation_config(
    task: str = "residual_walk",
    terrain_scale: float = 1.0,
    max_steps: int = 1000,
    settle_steps: int = 500,
    command_range: tuple[float, float] | None = None,
) -> EnvConfig:
    """The spec's episodes on the rough world, starts spread over the terrain."""
    return get_task(task).config_type(
        randomize=True,
        position_noise=START_SPREAD,
        terrain_scale=terrain_scale,
        max_episode_steps=max_steps,
        settle_steps=settle_steps,
        command_range=command_range,
    )


def base_gait_config(world: str, **overrides) -> EnvConfig:
    """The base-gait check's setup (docs/base_gait.md, docs/physics.md): starts from
    standing (no settling), yaw perturbed by ±0.1 rad; on the rough world, starts
    spread over the terrain by BASE_GAIT_SPREAD."""
    spread = (0.0, 0.0) if "flat" in world else BASE_GAIT_SPREAD
    config = EnvConfig(
        model_path=world,
        settle_steps=0,
        randomize=True,
        position_noise=spread,
        yaw_noise=0.1,
        tilt_noise=0.0,
    )
    return dataclasses.replace(config, **overrides)
