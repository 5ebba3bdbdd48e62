"""Older runs' records: config.json files that stored a run's flags, and their migration.

Until schema 2, config.json held rwalk-train's (or rwalk-train-torchrl's) flat flags
under ``"args"``, and every consumer re-ran the preset code on them. ``TrainArgs``
and ``TrainingEnv`` are those flags (kept so that such files, and code that builds
flags, still work); ``from_flags`` is the one migration that turns them into the
resolved configs a record now holds (``rwalk.rl.config.Training``).
"""

from __future__ import annotations

import dataclasses
import typing
from dataclasses import MISSING, dataclass
from typing import Any

from rwalk import presets
from rwalk.config import MAX_SETTLE_STEPS, MAX_SPEED, MAX_STEPS, EnvConfig
from rwalk.configdata import RecordError, decode, shown
from rwalk.levels import DEFAULT_KINDS, TerrainLevels
from rwalk.rewards import GaitCosts
from rwalk.rl.config import (
    PREDATING,
    Preset,
    RunConfig,
    RunSettings,
    TrainConfig,
    Training,
    resolved,
)
from rwalk.rl.torchrl_config import TorchRLConfig, TorchRLTraining
from rwalk.tasks.registry import TASKS, get_task
from rwalk.validation import flag, require_at_least, require_at_most, require_in

#: Flags of older versions that a saved flag-form config.json may hold: dropped.
RETIRED_FLAGS = ("curriculum_iterations",)


@dataclass(frozen=True)
class TrainingEnv:
    """The envs of a training as schema-1 flags: task, count and world."""

    task: str = "residual_walk"
    """task: residual_walk or adaptive_gait"""
    num_envs: int = 1024
    """parallel envs"""
    robust: bool = True
    """the robust world (``rwalk.presets.ROBUST``), else one rough world"""
    terrain_scale: float = 1.0
    """not robust: roughness of the one rough world, 0..1"""
    settle_steps: int = presets.TRAINING.settle_steps
    """zero-residual steps at each start"""
    settle_pool_fraction: float = presets.SETTLE_POOL_FRACTION
    """settled starts kept ready, as a fraction of num_envs"""
    settle_reuse: int = presets.TRAINING.settle_reuse
    """resets served by each pooled start"""
    max_episode_steps: int = EnvConfig.max_episode_steps
    """episode length (50 Hz)"""
    command_range: tuple[float, ...] = ()
    """LOW HIGH m/s of each episode's target velocity (none: the gait's)"""
    start_spread: float = 0.5
    """adaptive_gait: spread of the starting gait parameters"""
    gait_action: str = "delta"
    """adaptive_gait: how the action's first four values move the gait"""
    costs: bool = False
    """add the gait costs to the reward"""
    clearance_weight: float = GaitCosts.clearance
    """with costs: the clearance cost's size"""
    terrain_kinds: tuple[str, ...] = DEFAULT_KINDS
    """the robust world's kinds of tile"""
    demote: float = 0.35
    """the robust world's curriculum: the fraction of the expected distance below which an
    env goes a level down"""

    def __post_init__(self) -> None:
        require_at_least(self, 1, "num_envs", "settle_reuse", "max_episode_steps")
        require_at_least(self, 0, "settle_steps")
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
        for name in ("start_spread", "gait_action"):  # options of another task's config
            for task in TASKS.values():
                try:
                    task.configure(task.config_type(), **{name: getattr(self, name)})
                except ValueError as error:
                    raise ValueError(f"{flag(name)}: {error}") from None
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
            raise ValueError(f"--command-range must be speeds within ±{MAX_SPEED:g} m/s, got "
                             f"{self.command_range}")  # fmt: skip

    @property
    def gait_costs(self) -> GaitCosts | None:
        """The reward's gait costs (None: without costs)."""
        return GaitCosts(clearance=self.clearance_weight) if self.costs else None

    @property
    def commands(self) -> tuple[float, float] | None:
        """The command range as the env config takes it (None: no commands)."""
        return tuple(float(v) for v in self.command_range) or None  # type: ignore[return-value]

    @property
    def env(self) -> EnvConfig:
        """The env config these flags made (``config()``), as a training's ``env``."""
        return self.config()

    def env_config(self, threads: int = 0) -> EnvConfig:
        """``config(threads)``, as a training's ``env_config``."""
        return self.config(threads)

    def config(self, threads: int = 0) -> EnvConfig:
        """The env config these flags made: the preset's env with the flags' fields set
        (the adaptive task's options where the task takes them: ``Task.configure``)."""
        env = Preset(
            self.task, self.robust, self.costs, self.settle_pool_fraction, recipe="plain"
        ).env(self.num_envs)
        changes: dict[str, Any] = {
            "settle_steps": self.settle_steps, "settle_reuse": self.settle_reuse,
            "max_episode_steps": self.max_episode_steps, "num_threads": threads,
            "command_range": self.commands, "costs": self.gait_costs,
        }  # fmt: skip
        if self.robust:
            changes["terrain_levels"] = TerrainLevels(kinds=self.terrain_kinds, demote=self.demote)
        else:
            changes["terrain_scale"] = self.terrain_scale
        env = dataclasses.replace(env, **changes)
        return get_task(self.task).configure(env, start_spread=self.start_spread,
                                             gait_action=self.gait_action)  # fmt: skip


def _default(f: dataclasses.Field) -> Any:
    return f.default if f.default is not MISSING else f.default_factory()  # type: ignore[misc]


def flat(name: str, parts: dict[str, type], **defaults) -> type:
    """One frozen dataclass with every field of the config dataclasses ``parts`` (the
    schema-1 flags: one flag per field), offering each part as the attribute of its key
    (``args.train``); ``defaults`` override fields' defaults."""
    owners: dict[str, str] = {}
    specs = []
    for key, part in parts.items():
        for f in dataclasses.fields(part):
            owners[f.name] = key
            value = defaults.get(f.name, _default(f))
            specs.append((f.name, f.type, dataclasses.field(default=value)))

    def part_of(key: str) -> property:
        return property(lambda self: parts[key](**{
            f: getattr(self, f) for f, owner in owners.items() if owner == key}))  # fmt: skip

    def post_init(self) -> None:
        for key in parts:
            getattr(self, key)  # each part checks its own fields

    namespace = {key: part_of(key) for key in parts} | {"__post_init__": post_init}
    return dataclasses.make_dataclass(name, specs, frozen=True, namespace=namespace)


#: rwalk-train's schema-1 flags (``args.run``, ``args.env``, ``args.train``).
TrainArgs = flat("TrainArgs", {"run": RunConfig, "env": TrainingEnv, "train": TrainConfig})


#: rwalk-train-torchrl's schema-1 flags.
TorchRLArgs = flat(
    "TorchRLArgs", {"run": RunSettings, "env": TrainingEnv, "train": TorchRLConfig},
    log_dir="logs/torchrl", max_iterations=50, num_envs=256,
)  # fmt: skip
#: Each trainer's schema-1 flags and the training they migrate to.
FLAG_FORMS = {"rsl_rl": (TrainArgs, Training), "torchrl": (TorchRLArgs, TorchRLTraining)}


def from_flags(args) -> Any:
    """The one migration of a schema-1 record: the resolved configs of a run from its
    flags (``TrainArgs`` or ``TorchRLArgs``), as the schema-1 code built them.

    Raises:
        ValueError: naming the flag, for flags that make no training.
    """
    kind = next(training for flags, training in FLAG_FORMS.values() if isinstance(args, flags))
    env = dataclasses.replace(args.env.config(), num_threads=0)  # threads: the run's
    preset = Preset(args.task, args.robust, args.costs, args.settle_pool_fraction, recipe="plain")
    if kind is not Training:
        return kind(env=env, preset=preset, num_envs=args.num_envs, train=args.train,
                    run=args.run)  # fmt: skip
    before = {name: value for name, value in PREDATING.items() if getattr(args.train, name) is None}
    train = dataclasses.replace(args.train, **before)  # what the schema-1 code trained with
    return resolved(Training(env=env, preset=preset, num_envs=args.num_envs, train=train,
                             run=args.run))  # fmt: skip


def migrate(values: Any, trainer: str = "rsl_rl") -> Any:
    """The training of a schema-1 record's ``"args"`` (``values``, JSON) of ``trainer``:
    each flag checked against its declared type (a run saved before ``robust`` existed
    trained without it; ``RETIRED_FLAGS`` are dropped), then ``from_flags``.

    Raises:
        ValueError (``RecordError``): naming the first unknown key, a flag of the wrong
            type, or the flag a check refused.
    """
    cls = FLAG_FORMS[trainer][0]
    if not isinstance(values, dict):
        raise RecordError(f"must be an object of flags, got {shown(values)}")
    hints = typing.get_type_hints(cls)
    unknown = [key for key in values if key not in hints and key not in RETIRED_FLAGS]
    if unknown:
        raise RecordError(f"unknown key {shown(str(unknown[0]))} (known: {', '.join(hints)})")
    flags = {key: decode(hints[key], value, flag(key))
             for key, value in ({"robust": False} | values).items() if key in hints}  # fmt: skip
    return from_flags(cls(**flags))


def as_training(args) -> Any:
    """``args`` as a training: itself, or the migration of schema-1 flags."""
    return from_flags(args) if isinstance(args, tuple(f for f, _ in FLAG_FORMS.values())) else args
