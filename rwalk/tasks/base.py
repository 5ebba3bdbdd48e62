"""What a task declares.

A task is one small module: a ``Task`` subclass that says how an action
becomes servo targets (``act``), which named observation pieces make its spec
observation and which extra pieces the views offer (``pieces``, ``extras``),
its reward terms (``reward_terms``, each a ``RewardTerm``), and what it keeps
per env across a reset (``reset``). It gets the narrow things it needs: its
config, the world (gait controller, leg geometry, timing) and N. The core owns
everything else: the simulation, seeding, resets and settling, termination
and episode bookkeeping. Specs, ``reward_terms`` keys,
``info["reward_components"]``, TensorBoard tags, rsl-rl observation groups and
the docs' tables are all built from these declarations.
"""

from __future__ import annotations

import dataclasses
from typing import Any, ClassVar

import numpy as np
import torch
from torch import Tensor

from rwalk import rng
from rwalk.commands import CommandWeights
from rwalk.config import EnvConfig, convert, with_fields
from rwalk.mirror import Mirror
from rwalk.observations import COMMON_PIECES, PRIVILEGED_PIECES, ObsPiece, piece_catalog
from rwalk.rewards import RewardTerm, cost_terms, shaping_terms, spec_terms
from rwalk.world import World

#: Random stream of the per-episode velocity commands (see ``rwalk.rng``).
COMMAND_STREAM = "command"


@dataclasses.dataclass(frozen=True)
class Recipe:
    """How rwalk-train trains a task by default where its world is robust (``--recipe
    precise``): what it changes from the plain defaults, each a flag's value; the run's
    record holds them resolved, as it holds every flag (docs/learning.md)."""

    env_fields: dict[str, Any]
    """The env config's fields it sets, each by its flag's path after --env. with
    underscores (--env.costs.power 2: ``{"costs.power": 2.0}``; --terrain-kinds, short for
    --env.terrain-levels.kinds: ``"terrain_levels.kinds"``); a part the robust world
    leaves out (the gait costs, the shaping) starts at its defaults (``with_fields``)."""
    train: dict[str, Any]
    """``TrainConfig`` fields (--teacher: ``{"teacher": True}``)."""
    max_iterations: int
    """--max-iterations (the teacher's, where ``train`` trains one)."""
    student_env_share: float = 1.0
    """The one command's student's envs as a share of --num-envs (--student-num-envs; 1:
    the teacher's)."""

    #: ``train``'s fields that make a teacher and its student: left out where the command
    #: line trains neither (--no-teacher, --distill), so that those flags work alone.
    TEACHER_FIELDS = ("teacher", "teacher_obs", "student_iterations", "student_actor",
                      "distill_levels", "student_num_envs",
                      "student_nominal_physics_iterations", "finetune_iterations")  # fmt: skip
    #: ``train``'s fields of the student alone (its fine-tune included): left out too where
    #: the command line trains no student (--student-iterations 0), so that a teacher
    #: trains alone.
    STUDENT_FIELDS = ("distill_levels", "student_num_envs", "student_nominal_physics_iterations",
                      "finetune_iterations")  # fmt: skip

    def env(self, env: EnvConfig) -> EnvConfig:
        """``env`` (a robust training's) as this recipe trains it."""
        return with_fields(env, self.env_fields)

    def train_fields(self, num_envs: int, *, teacher: bool = True,
                     student: bool = True) -> dict[str, Any]:  # fmt: skip
        """``train`` for a teacher on ``num_envs`` envs (its student on
        ``student_env_share`` of them), without the teacher's and student's fields where
        not ``teacher``, and without the student's where not ``student``."""
        fields = dict(self.train)
        if self.student_env_share != 1:
            fields["student_num_envs"] = max(1, round(num_envs * self.student_env_share))
        left_out = (() if teacher else self.TEACHER_FIELDS) + (
            () if student else self.STUDENT_FIELDS)  # fmt: skip
        return {k: v for k, v in fields.items() if k not in left_out}


class Task:
    """Base of every task; a subclass is one task (see the module docstring).

    Args:
        config: the task's config.
        world: the model's gait controller, leg geometry and timing.
        num_envs: N. A task keeps per-env state as tensors of batch size N; no
            Python loop per env.
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
    """Whether a one-env view may step through ``rwalk.envs.single_step``'s float
    pipeline (which implements this task's step on numpy and floats)."""
    acting_fields: ClassVar[tuple[str, ...]] = (
        "gait", "residual_scale", "control_dt", "decimation", "physics", "command_range",
    )  # fmt: skip
    """Config fields a trained policy acts through (its gait, action scale, timing,
    physics and commands): an evaluation env takes them from the training's record
    (``evaluation_config``)."""
    nominal_physics_share: ClassVar[float] = 0.0
    """rwalk-train's default --nominal-physics-iterations for this task where the physics
    is randomised, as a share of --max-iterations: the last iterations drawing the
    model's own physics (docs/learning.md)."""
    late_stage: ClassVar[tuple[float, dict[str, float]] | None] = None
    """rwalk-train's default --late-iterations for this task where the physics is
    randomised: (its share of --max-iterations, the stage's values: ``{"late_tracking":
    200.0}`` is --late-tracking 200); None: no such stage (docs/learning.md)."""
    recipe: ClassVar[Recipe | None] = None
    """rwalk-train's training of this task where its world is robust, beyond the plain
    defaults (``--recipe precise``); None: the plain defaults."""
    action_fields: ClassVar[tuple[str, ...]] = ()
    """Config fields that say what the action's values mean beyond its layout: a policy
    acts only in an env whose are its training's (``rwalk.evaluation.load_policy``)."""

    def __init__(self, config: EnvConfig, world: World, num_envs: int) -> None:
        self.config = config
        self.world = world
        self.num_envs = num_envs
        self.target = torch.full((num_envs,), config.expected_velocity, dtype=torch.float64)
        """Target velocity of each env's episode. Shape: (N,). m/s."""
        self.draws = torch.zeros(num_envs, dtype=torch.long)
        """Commands drawn so far by each env (the counter of its next draw). Shape: (N,)."""
        self.action = torch.zeros(num_envs, self.action_dim, dtype=torch.float64)
        """Each env's action of its last step, checked and clipped (zero at an episode's
        start: the base gait). Shape: (N, action_dim)."""
        self.last_action = torch.zeros_like(self.action)
        """Each env's action of the step before. Shape: (N, action_dim)."""
        curriculum = config.command_curriculum
        self.commands = (None if curriculum is None
                         else CommandWeights(curriculum, config.command_range))  # fmt: skip
        """The command curriculum's bins (``config.command_curriculum``), or None."""
        self._seed = 0
        if config.costs is not None:
            config.costs.check_reach(world.geometry, config.top_speed)

    # ------------------------------------------------------------ configs
    @classmethod
    def configure(cls, config: EnvConfig, **options: Any) -> EnvConfig:
        """``config`` with those ``options`` that this task's config has (the others are
        another task's options, e.g. the adaptive task's ``gait_action``: ignored)."""
        own = {f.name for f in dataclasses.fields(cls.config_type)}
        return dataclasses.replace(config, **{k: v for k, v in options.items() if k in own})

    @classmethod
    def training_config(cls, world: EnvConfig) -> EnvConfig:
        """This task's training env in ``world`` (a preset: ``rwalk.presets.TRAINING`` or
        ``ROBUST``, sized by ``training_env``)."""
        return convert(cls.config_type, world)

    @classmethod
    def evaluation_config(cls, trained: EnvConfig, episodes: EnvConfig, **changes: Any
                          ) -> EnvConfig:  # fmt: skip
        """The evaluation ``episodes`` (an ``EnvConfig``: world, starts, lengths) as this
        task's config, acting as the policy trained in ``trained`` does
        (``acting_fields``), with ``changes``."""
        acting = {name: getattr(trained, name) for name in cls.acting_fields}
        return dataclasses.replace(convert(cls.config_type, episodes, **acting), **changes)

    @classmethod
    def deploy_spec(cls, core: Any) -> dict[str, Any] | None:
        """What ``rwalk.deploy`` needs beside the exported network to run this task's
        policy on a robot (``rwalk.export.deploy_spec`` adds the timing and the legs);
        None: the task has no deploy runtime, and an export carries no ``deploy``
        section (the runtime refuses it, naming the task)."""
        return None

    # ------------------------------------------------------------ declarations
    @classmethod
    def pieces(cls) -> dict[str, ObsPiece]:
        """Every named observation piece of this task (the views choose from these):
        COMMON_PIECES and ``last_action``, the policy's own last command (the one a
        servo delay still holds in flight), exact: a robot knows what it sent."""
        last_action = ObsPiece(
            cls.action_dim,
            lambda s: s.task.action,
            "the policy's action of the last step, checked and clipped (zero at an episode's "
            "start)",
            mirror=cls.action_mirror(),
        )
        return {**COMMON_PIECES, "last_action": last_action}

    @classmethod
    def extras_for(cls, config: EnvConfig) -> tuple[str, ...]:
        """Pieces the views offer beside the spec observation for a ``config``
        (``command`` when it draws commands)."""
        commanded = config.command_range is not None
        return ("phase", "lateral_offset", *(("command",) if commanded else ()))

    def extras(self) -> tuple[str, ...]:
        """``extras_for`` this task's config."""
        return self.extras_for(self.config)

    def privileged(self) -> tuple[str, ...]:
        """Pieces only a critic sees (PRIVILEGED_PIECES), offered when the config varies
        the world: randomised physics, pushes, noise or terrain levels."""
        return PRIVILEGED_PIECES if self.config.varies else ()

    def reward_terms(self) -> tuple[RewardTerm, ...]:
        """The reward's terms, in the order they are added and reported: the spec's, then
        the gait costs and the training's shaping when the config has them."""
        cfg = self.config
        costs = () if cfg.costs is None else cost_terms(cfg.costs, self.world)
        map_kinds = cfg.terrain_levels.kinds if cfg.terrain_levels is not None else ()
        shaping = () if cfg.shaping is None else shaping_terms(cfg.shaping, map_kinds)
        return spec_terms(cfg.reward_weights) + costs + shaping

    @classmethod
    def action_mirror(cls) -> Mirror:
        """The left-right mirror of an action (``rwalk.mirror``), for symmetry augmentation.

        Raises:
            ValueError: naming the task, if it declares none.
        """
        raise ValueError(f"task {cls.name!r} declares no action mirror (Task.action_mirror)")

    @property
    def observation_dim(self) -> int:
        """Width of the spec observation."""
        return piece_catalog(self.pieces(), self.observation)["observation"][0]

    # ------------------------------------------------------------ behaviour
    def seed(self, seed: int) -> None:
        """Key the task's own random streams by ``seed`` and restart them."""
        self._seed = seed
        self.draws.zero_()

    def reset(self, rows: Tensor) -> None:
        """Start the episodes of ``rows``, whose starts were just settled. Shape: (M,)."""
        raise NotImplementedError

    def draw_commands(self, rows: Tensor) -> None:
        """Each env of ``rows`` draws its episode's target velocity from
        ``config.command_range`` (with a command curriculum, from its unlocked bins): env
        i's k-th from the key (seed + i, "command", k)."""
        low_high = self.config.command_range
        if low_high is None:
            return
        if self.commands is not None:
            self.target[rows] = self.commands.draw(self.uniform(rows, COMMAND_STREAM,
                                                                self.draws, 2))  # fmt: skip
            return
        u = self.uniform(rows, COMMAND_STREAM, self.draws, 1)[:, 0]
        self.target[rows] = low_high[0] + u * (low_high[1] - low_high[0])

    def judge_commands(self, rows: Tensor, walked: Tensor, speed_error: Tensor,
                       fell: Tensor) -> None:  # fmt: skip
        """The episodes of ``rows`` end: with a command curriculum, the ones that ran their
        whole length (``config.max_episode_steps``) and tracked their command widen it
        (``CommandWeights.update``); an episode cut short (rsl-rl's randomly shortened
        first ones, a reset from outside) counts nothing, as walk-these-ways divides an
        episode's sum by the whole length. walked, speed_error, fell: every env's steps,
        summed |v_x - v*| (m/s) and fall. Each shape: (N,)."""
        if self.commands is not None:
            steps = walked[rows]
            whole = torch.where(steps >= self.config.max_episode_steps, steps, 0)
            self.commands.update(self.target[rows], whole, speed_error[rows], fell[rows])

    def redraw_commands(self, walked: Tensor) -> None:
        """Within episodes: the envs that have walked a whole number of
        ``config.command_interval`` since their start draw a new target velocity.

        Args:
            walked: env steps each episode has walked (after this step). Shape: (N,).
        """
        interval = self.config.command_interval
        if interval is None or self.config.command_range is None:
            return
        every = max(1, round(interval / self.world.control_dt))
        rows = ((walked % every) == 0).nonzero().squeeze(-1)
        if rows.numel():
            self.draw_commands(rows)

    def uniform(self, rows: Tensor, stream: str, counters: Tensor, n: int) -> Tensor:
        """n uniform [0, 1) numbers per env of ``rows`` from env i's key (seed + i,
        ``stream``, counters[i]); each counter then moves on by one. Shape: (M, n) float64."""
        return rng.uniform_rows(self._seed, rows, stream, counters, n)

    def act(self, action: Tensor) -> tuple[np.ndarray, Tensor]:
        """Servo targets for the next ``world.decimation`` substeps, and advance the gait.

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
        if self.config.command_range is None:
            return self.config.expected_velocity
        return self.target

    @property
    def phase(self) -> Tensor:
        """Gait phase in [0, 1) at the start of the next step. Shape: (N,)."""
        raise NotImplementedError

    @property
    def sensed_phase(self) -> Tensor:
        """Gait phase in [0, 1) at the start of the last substep of the step just taken,
        whose sensors the step reports. Shape: (N,)."""
        raise NotImplementedError

    def phase_features(self) -> Tensor:
        """(sin 2πφ, cos 2πφ) of the gait phase. Shape: (N, 2)."""
        raise NotImplementedError

    def state(self) -> dict[str, Tensor]:
        """Tensors to keep when the core is pickled: per env, and the command
        curriculum's weights (per bin) where there is one."""
        commands = {} if self.commands is None else {"command_weights": self.commands.weights}
        return {"target": self.target, "draws": self.draws, "action": self.action,
                "last_action": self.last_action} | commands  # fmt: skip

    def remember(self, action: Tensor) -> None:
        """Keep this step's action (checked, clipped) and the one before it."""
        self.last_action.copy_(self.action)
        self.action.copy_(action)

    def forget_actions(self, rows: Tensor) -> None:
        """New episodes in ``rows`` start from the zero action. Shape: (M,)."""
        self.action[rows] = 0.0
        self.last_action[rows] = 0.0
