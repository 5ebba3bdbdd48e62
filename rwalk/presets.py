"""The configurations runners share: training and evaluation episodes of each task.

One place for the start spread, pooled settling and world, so that both trainers,
the evaluator and the benchmark run the same episodes. ``TrainingEnv`` is the
training's envs as a config (the trainers' env flags map one to one onto it);
``robust_world`` is the robust training's world.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from rwalk.cli import require_at_least, require_at_most, require_in
from rwalk.config import MAX_ENVS, MAX_SETTLE_STEPS, MAX_SPEED, MAX_STEPS, EnvConfig
from rwalk.levels import DEFAULT_KINDS, TerrainLevels
from rwalk.observations import ObservationNoise
from rwalk.perturbations import Pushes
from rwalk.randomization import Randomization
from rwalk.rewards import GaitCosts
from rwalk.tasks import get_task
from rwalk.tasks.adaptive_gait import GAIT_ACTIONS

__all__ = [
    "BASE_GAIT_SPREAD", "PAD_SPREAD", "START_SPREAD", "TrainingEnv", "base_gait_config",
    "evaluation_config", "get_task", "robust_parts", "robust_world", "training_config",
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
    levels: TerrainLevels | None = None,
    costs: GaitCosts | None = None,
    gait_action: str = "delta",
) -> EnvConfig:
    """The training env: pooled settling and starts spread; for adaptive_gait,
    starting parameters spread by ``start_spread`` (see ``AdaptiveGaitConfig.start_spread``).

    ``robust``: in the robust world (``robust_world``: a terrain-levels map with its
    curriculum, physics randomisation, pushes and observation noise; ``terrain_scale``
    is ignored).
    Otherwise one rough world at ``terrain_scale``, starts spread over it.
    ``costs``: the reward's gait costs (``rwalk.rewards.GaitCosts``); ``gait_action``:
    the adaptive task's ``AdaptiveGaitConfig.gait_action`` (other tasks ignore both
    start_spread and gait_action).
    """
    kind = get_task(task).config_type
    adaptive = "gait_action" in kind.__dataclass_fields__
    extra = {"start_spread": start_spread, "gait_action": gait_action} if adaptive else {}
    if robust:
        extra |= robust_world() | {"position_noise": PAD_SPREAD}
        if levels is not None:
            extra["terrain_levels"] = levels
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
        costs=costs,
        **extra,
    )


def robust_world() -> dict:
    """The robust world: a terrain-levels map with its curriculum, physics randomisation,
    pushes and observation noise, each at its defaults (``EnvConfig`` fields)."""
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
    gait_action: str = "delta",
) -> EnvConfig:
    """The spec's episodes on the rough world, starts spread over the terrain;
    ``gait_action``: the adaptive task's (``AdaptiveGaitConfig.gait_action``; other tasks
    ignore it)."""
    kind = get_task(task).config_type
    extra = {"gait_action": gait_action} if "gait_action" in kind.__dataclass_fields__ else {}
    return kind(
        **extra,
        randomize=True,
        position_noise=START_SPREAD,
        terrain_scale=terrain_scale,
        max_episode_steps=max_steps,
        settle_steps=settle_steps,
        command_range=command_range,
    )


#: The worlds the base-gait check walks on, by name (docs/base_gait.md, docs/physics.md).
BASE_GAIT_WORLDS = {"flat": "model/world_flat.xml", "rough": "model/world_train.xml"}


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


#: The robust world's parts by their old name.
robust_parts = robust_world


@dataclass(frozen=True)
class TrainingEnv:
    """The envs a training steps: task, count and world (the env flags of both trainers)."""

    task: str = "residual_walk"
    """task: residual_walk or adaptive_gait"""
    num_envs: int = 1024
    """parallel envs (under torchrun: per rank; with collectors: per worker)"""
    robust: bool = True
    """train for worlds never seen: per-env terrain levels with their curriculum, physics
    randomisation, pushes, observation noise and a privileged critic (--no-robust: one rough
    world at --terrain-scale)"""
    terrain_scale: float = 1.0
    """--no-robust: roughness of the one rough world, 0..1"""
    settle_steps: int = 100
    """zero-residual steps at each start"""
    settle_pool_fraction: float = 0.25
    """settled starts kept ready, as a fraction of num_envs"""
    settle_reuse: int = 4
    """resets served by each pooled start"""
    max_episode_steps: int = 1000
    """episode length (50 Hz)"""
    command_range: tuple[float, ...] = dataclasses.field(default=(), metadata={"item": float})
    """draw each episode's target velocity from LOW HIGH m/s, shown to the policy as the
    piece command (none: the gait's step_length / cycle_time)"""
    start_spread: float = 0.5
    """adaptive_gait: episodes start from gait parameters spread by this fraction of each
    range (0: the starting gait; residual_walk ignores it)"""
    gait_action: str = "delta"
    """adaptive_gait: the action's first four values are per-step deltas of the gait
    parameters (delta, the contract) or targets within their ranges, approached at the
    delta rate (target)"""
    costs: bool = False
    """add the gait costs to the reward: swing clearance below a target above the ground,
    feet slipping, servo power (rwalk.rewards.GaitCosts)"""
    clearance_weight: float = GaitCosts.clearance
    """--costs: the clearance cost's size, per metre that a mid-swing foot passes below
    the target above the ground"""
    terrain_kinds: tuple[str, ...] = dataclasses.field(
        default=DEFAULT_KINDS, metadata={"item": str}
    )
    """the robust world's kinds of tile (rough, slopes, steps, stones, flat), one per fifth
    or quarter of the envs"""
    demote: float = 0.35
    """the robust world's curriculum: an env that walked less than this fraction of the
    expected distance (or fell) goes a level down"""

    def __post_init__(self) -> None:
        require_at_least(self, 1, "num_envs", "settle_reuse", "max_episode_steps")
        require_at_least(self, 0, "settle_steps")
        require_at_most(self, MAX_ENVS, "num_envs")
        require_at_most(self, MAX_STEPS, "max_episode_steps", "settle_reuse")
        require_at_most(self, MAX_SETTLE_STEPS, "settle_steps")
        require_in(self, "start_spread", 0.0, 1.0)
        require_in(self, "terrain_scale", 0.0, 1.0)
        require_in(self, "settle_pool_fraction", 0.0, 1.0, low_open=True)
        get_task(self.task)  # ValueError listing the known tasks
        if self.costs:
            try:
                GaitCosts(clearance=self.clearance_weight)
            except ValueError as error:
                raise ValueError(f"--clearance-weight: {error}") from None
        elif self.clearance_weight != GaitCosts.clearance:
            raise ValueError("--clearance-weight needs --costs: it weighs one of the gait costs")
        if self.gait_action not in GAIT_ACTIONS:
            raise ValueError(
                f"--gait-action must be one of {', '.join(GAIT_ACTIONS)}, got {self.gait_action!r}"
            )
        require_in(self, "demote", 0.0, TerrainLevels.promote)
        try:
            TerrainLevels(kinds=self.terrain_kinds)
        except ValueError as error:
            raise ValueError(f"--terrain-kinds: {error}") from None
        if self.command_range and (
            len(self.command_range) != 2 or not self.command_range[0] <= self.command_range[1]
        ):
            raise ValueError(f"--command-range must be LOW HIGH, got {self.command_range}")
        if any(not abs(v) <= MAX_SPEED for v in self.command_range):
            raise ValueError(
                f"--command-range must be speeds within ±{MAX_SPEED:g} m/s, got "
                f"{self.command_range}"
            )

    @property
    def gait_costs(self) -> GaitCosts | None:
        """The reward's gait costs (None: without --costs)."""
        return GaitCosts(clearance=self.clearance_weight) if self.costs else None

    @property
    def commands(self) -> tuple[float, float] | None:
        """The command range as the env config takes it (None: no commands)."""
        return tuple(float(v) for v in self.command_range) or None  # type: ignore[return-value]

    def config(self, threads: int = 0) -> EnvConfig:
        """The env config of these envs, its physics on ``threads`` threads (0: all cores)."""
        return training_config(
            self.task,
            num_envs=self.num_envs,
            robust=self.robust,
            terrain_scale=self.terrain_scale,
            settle_steps=self.settle_steps,
            settle_pool_fraction=self.settle_pool_fraction,
            settle_reuse=self.settle_reuse,
            max_episode_steps=self.max_episode_steps,
            threads=threads,
            command_range=self.commands,
            start_spread=self.start_spread,
            levels=TerrainLevels(kinds=self.terrain_kinds, demote=self.demote),
            costs=self.gait_costs,
            gait_action=self.gait_action,
        )
