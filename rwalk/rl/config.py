"""The training's configs: the preset, the envs, rsl-rl's algorithm and models, the run.

A training is one ``Training``: its ``env`` is the task's whole ``EnvConfig``
(world, episodes, reward, variations), ``train`` holds PPO's settings, the models
and what the policy and critic read, ``run`` says where it writes and how long it
runs, and ``preset`` says which task and world its configs started from
(``rwalk.presets.training_env``). The command line is this dataclass (tyro: every
nested field a flag, ``--env.costs.clearance 3000``; ``rwalk.rl.cli``), and a run's
record, config.json, is this dataclass resolved (``rwalk.rl.record``): play, the
reports, export, resume and distillation build from it, never from preset code.

``observation_groups`` is the one rule for which pieces the policy and the critic
read; a training resolves it once (``resolved``) and its record keeps the result.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Generic, TypeVar

from tyro.conf import OmitArgPrefixes

from rwalk.config import MAX_ENVS, MAX_THREADS, EnvConfig
from rwalk.levels import KNOWN_KINDS
from rwalk.observations import PRIVILEGED_PIECES, SIMULATOR_PIECES, piece_catalog
from rwalk.presets import SETTLE_POOL_FRACTION, training_env
from rwalk.randomization import PHYSICS_RANGES
from rwalk.rewards import Shaping
from rwalk.rl.distributed import DEFAULT_TIMEOUT_S
from rwalk.rng import SEED_LIMIT
from rwalk.tasks.registry import get_task
from rwalk.validation import (
    flag,
    require_at_least,
    require_at_most,
    require_choice,
    require_in,
    require_positive,
    show_flag,
)

#: The actor's (or student's) models: an MLP, or a recurrent layer before the MLP.
ACTORS = ("mlp", "gru", "lstm")
#: Most iterations of a run, and most of the counts per iteration.
MAX_ITERATIONS = 10**9
#: Most layers, and most units in a layer, of the actor's and the critic's MLPs.
MAX_LAYERS = 8
MAX_WIDTH = 4096
#: Most weight of --distill-smoothness (the imitation's own weight is 1).
MAX_SMOOTHNESS = 1000.0
#: --late-iterations' values: the TrainConfig field, and the EnvConfig part and field it
#: sets in that stage.
LATE_VALUES = {
    "late_tracking": ("shaping", "tracking"),
    "late_sigma": ("shaping", "sigma"),
    "late_sigma_per_speed": ("shaping", "sigma_per_speed"),
    "late_clearance_target": ("costs", "clearance_target"),
    "late_clearance_target_per_speed": ("costs", "clearance_target_per_speed"),
    "late_action_rate": ("shaping", "action_rate"),
}
#: rwalk-train's --logger choices (rsl-rl's writers).
LOGGERS = ("tensorboard", "wandb")


@dataclass(frozen=True)
class RunSettings:
    """Where a training writes, from what it goes on, and how long it runs."""

    log_dir: str = "logs/rwalk"
    """output folder of this run"""
    seed: int = 0
    """seed of the envs and of torch (under torchrun, rank r seeds its envs with seed + r *
    (num_envs + its settled-start pool) and torch with seed + r)"""
    resume: str = ""
    """continue from this checkpoint file, or from the newest checkpoint that loads in this
    run folder (with the run's --log-dir, --seed, --max-iterations, --threads and
    --share-cores unless given)"""
    overwrite: bool = False
    """train in a --log-dir that holds another run's checkpoints: delete its checkpoints (all
    but the --resume file) and, unless resuming from it, its TensorBoard event files"""
    max_iterations: int = 300
    """iterations in total, counting those of --resume"""
    max_minutes: float = math.inf
    """stop at a checkpoint after this much wall time (with --student-iterations: each
    stage's)"""
    save_interval: int = 25
    """save a checkpoint when the iteration is a multiple of this, and at the end"""
    threads: int = 0
    """physics and torch threads (0 = all cores; under torchrun or with several collectors,
    per process: 0 = the machine's cores / its processes)"""
    share_cores: bool = False
    """torch on one thread while other processes keep this one's cores busy (two trainings
    then share the cores instead of fighting over them), on --threads again when they are
    free (rwalk.threads.SharedCores; not under torchrun or with several collectors, whose
    processes keep their shares). Off by default: where torch rounds differently on one
    thread and on several (a Xeon with AVX-512 here, docs/performance.md), what the run
    learns would then depend on what else ran on the machine; off, a run is reproducible
    to the byte on one machine"""

    def __post_init__(self) -> None:
        require_at_least(self, 1, "max_iterations", "save_interval")
        require_at_least(self, 0, "threads", "seed")
        require_at_most(self, SEED_LIMIT - 1, "seed")
        require_at_most(self, MAX_ITERATIONS, "max_iterations", "save_interval")
        require_at_most(self, MAX_THREADS, "threads")
        require_positive(self, "max_minutes", finite=False)
        if not self.log_dir.strip():
            raise ValueError("--log-dir must name a folder, got ''")


@dataclass(frozen=True)
class RunConfig(RunSettings):
    """rwalk-train's run: ``RunSettings``, its exports, its process group and its logger."""

    export: bool = True
    """export TorchScript and ONNX at the end"""
    dist_timeout: float = DEFAULT_TIMEOUT_S
    """under torchrun: seconds a rank waits for the others (in any exchange) before the
    whole training fails; longer than building the envs or one iteration"""
    logger: str = "tensorboard"
    """where the metrics go: tensorboard (event files in --log-dir), or wandb (Weights &
    Biases through rsl-rl's writer, and the event files too; pip install 'rwalk[wandb]')"""
    wandb_project: str = "rwalk"
    """--logger wandb: the W&B project"""
    run_name: str = ""
    """--logger wandb: the W&B run's name (default: the --log-dir folder's name)"""

    def __post_init__(self) -> None:
        super().__post_init__()
        require_positive(self, "dist_timeout")
        require_choice(self, "logger", LOGGERS)
        if self.logger == "wandb" and not self.wandb_project.strip():
            raise ValueError("--wandb-project must name a project, got ''")


@dataclass(frozen=True)
class TrainConfig:
    """rsl-rl's PPO, its actor and critic, and what the policy reads."""

    num_steps_per_env: int = 24
    """rollout length per iteration"""
    reward_scale: float = 1e-3
    """reward multiplier seen by PPO (the env's reward is the spec's, ~300 per step)"""
    hidden_dims: tuple[int, ...] = (128, 128)
    """MLP layers of the actor and the critic"""
    init_noise_std: float = 0.1
    """initial action std"""
    learning_rate: float = 1e-3
    """Adam step (adaptive on KL)"""
    entropy_coef: float = 0.005
    """entropy bonus"""
    num_learning_epochs: int = 5
    """PPO epochs per iteration"""
    num_mini_batches: int = 4
    """minibatches per epoch"""
    gamma: float = 0.99
    """discount"""
    lam: float = 0.95
    """GAE lambda"""
    clip_param: float = 0.2
    """PPO ratio clip"""
    desired_kl: float = 0.01
    """target KL of the adaptive learning rate"""
    max_grad_norm: float = 1.0
    """gradient clip"""
    policy_obs: tuple[str, ...] = ()
    """observation pieces the policy sees (none: the rule of ``observation_groups``, resolved
    when the run starts: the observation, phase, lateral_offset and the task's command)"""
    critic_obs: tuple[str, ...] = ()
    """observation pieces the critic sees (none: the rule of ``observation_groups``: the
    policy's, and the privileged ones where the world varies)"""
    actor: str = "mlp"
    """the actor's (a student's) model: mlp, or a recurrent gru or lstm before the MLP layers
    (PPO then trains on whole trajectories; the critic is of the same kind)"""
    rnn_hidden_dim: int = 128
    """--actor gru/lstm: units of the recurrent layer"""
    teacher: bool = False
    """train a teacher: the actor also reads the privileged pieces (--teacher-obs: the drawn
    physics, the ground around the feet), which only a simulation has; distil it with
    --distill"""
    teacher_obs: tuple[str, ...] = PRIVILEGED_PIECES
    """--teacher: the privileged pieces its actor (and its critic) add to the policy's:
    physics (the drawn physics), heights (each foot's height over the ground under it and
    3 cm around it), heights_under_feet (under it only)"""
    distill: str = ""
    """train a blind student against this frozen teacher checkpoint, or the newest in this
    run folder (of an rwalk-train --teacher run), with rsl-rl's Distillation: the student
    reads the policy's pieces (with their noise)"""
    warm_start: str = ""
    """start the actor and the critic (weights, observation normalisers, action std) from
    this checkpoint file, or the newest in this run folder, of an rwalk-train run of this
    task whose actor and critic read the same pieces with the same models; unlike --resume,
    this run starts at iteration 0 with a fresh optimizer and curriculum, in this command's
    world (a policy trained in one world, fine-tuned in the robust one); or a distilled
    student's checkpoint, whose student becomes the actor (--warm-start-critic then names
    the critic)"""
    warm_start_critic: str = ""
    """--warm-start: start the critic from this checkpoint file, or the newest in this run
    folder, of an rwalk-train PPO run of this task whose critic reads the same pieces with
    the same model (--critic-obs, --critic, --hidden-dims); needed where --warm-start names a
    distilled student, which has no critic and whose action std never trained: both then
    come from this run (the student's teacher, for a PPO fine-tune of the student)"""
    warm_start_levels: bool = False
    """--warm-start: the curriculum starts where the warm start's checkpoint left it (each
    env on its terrain level; with another number of envs, on the level of one of its
    envs on the same kind of tile) instead of at the start level"""
    critic: str = ""
    """the critic's model: mlp, gru or lstm ('': the actor's, --actor)"""
    gradient_length: int = 15
    """--distill: steps whose losses add up before each gradient step (a recurrent student
    learns through them)"""
    distill_smoothness: float = 0.0
    """--distill, --student-iterations: beside the imitation's mean square error, this
    weight times the mean square of the student's action change from one step to the next
    (rwalk.rl.distillation: smoother actions, measured against the delayed loop's
    oscillation in docs/learning.md); 0: rsl-rl's Distillation as it is"""
    lag_smoothness: float = 0.0
    """PPO with an MLP actor: beside PPO's loss, this weight times each minibatch's mean of
    L x Σ (μ − μ̄_prev)², the actor's mean action's change from its mean of the step
    before (at rollout), L the servo delay that applies in substeps (0 without one): a cost on
    the mean where the servos lag, with no price on the exploration noise (rwalk.rl.ppo;
    measured in docs/learning.md: the delayed loop worse, not better); the one command's
    student and fine-tune train without it; 0: rsl-rl's PPO as it is"""
    symmetry: bool = True
    """augment PPO's minibatches with the left-right mirrored states and actions (rsl-rl's
    symmetry augmentation) where rsl-rl allows it: PPO with an MLP actor (recurrent actors
    and distilled students train without it; docs/learning.md)"""
    nominal_physics_iterations: int | None = None
    """the last N of --max-iterations draw every new episode's physics at the model's own
    values (each --env.randomization range narrowed to it but --nominal-physics-keep's,
    latency 0), the optimizer, curriculum, terrain, pushes and noise going on
    (docs/learning.md); None: the task's share of --max-iterations with physics
    randomisation (Task.nominal_physics_share: residual_walk a third, 100 of the default
    300; adaptive_gait none), else 0"""
    nominal_physics_keep: tuple[str, ...] = ("friction",)
    """--nominal-physics-iterations: the --env.randomization ranges that stay as they are
    in that stage (none: every range narrowed)"""
    nominal_physics_entropy_coef: float | None = None
    """--nominal-physics-iterations: PPO's entropy bonus in that stage (None: --entropy-coef
    throughout); 0 lets the action noise shrink while the stage learns its precision, which
    bought precision and cost new-map falls on one seed of two (docs/learning.md)"""
    late_iterations: int | None = None
    """the last N of --max-iterations train with the reward's values that --late-tracking,
    --late-sigma, --late-sigma-per-speed, --late-clearance-target,
    --late-clearance-target-per-speed and --late-action-rate give (the costs moved on a
    policy that has climbed the curriculum; docs/adaptive.md), the optimizer, curriculum and
    episodes going on (a stage longer than the run: all of it, as a resume that shortens a run
    leaves it); 0: no such stage; None: the task's stage where the physics is randomised
    (Task.late_stage: residual_walk the last sixth, 50 of the default 300, with the speed kernel
    at --late-tracking 200, its terms at weight 0 before; the late flags given replace its
    values; adaptive_gait none), else 0"""
    late_tracking: float | None = None
    """--late-iterations: the training kernel's weight (--env.shaping.tracking) in that
    stage; None: unchanged"""
    late_sigma: float | None = None
    """--late-iterations: the training kernel's half-width (--env.shaping.sigma) in that
    stage, m/s; None: unchanged"""
    late_sigma_per_speed: float | None = None
    """--late-iterations: the kernel's growth with the target speed
    (--env.shaping.sigma-per-speed: half-width max(sigma, this x v*)) in that stage; None:
    unchanged"""
    late_clearance_target: float | None = None
    """--late-iterations: the gait costs' clearance target (--env.costs.clearance-target)
    in that stage, m; None: unchanged"""
    late_clearance_target_per_speed: float | None = None
    """--late-iterations: the clearance target's growth with the target speed
    (--env.costs.clearance-target-per-speed: max(clearance target, this x v*)) in that
    stage, s; None: unchanged"""
    late_action_rate: float | None = None
    """--late-iterations: the cost of the action's change from step to step
    (--env.shaping.action-rate) in that stage; None: unchanged"""
    flat_kinds: tuple[str, ...] = ()
    """the envs on these kinds of tile (of --terrain-kinds) walk their tile's level 0, flat
    at every kind, from iteration --flat-from until --flat-until, then walk the curriculum
    again, each from a level drawn uniformly from the map's (it goes on for the others
    throughout); none: no such window"""
    flat_from: int = 0
    """--flat-kinds: the window's first iteration"""
    flat_until: int | None = None
    """--flat-kinds: the iteration that ends the window (None: the run's end)"""
    student_iterations: int = 0
    """with --teacher: when the teacher is trained, distil it into a blind student for this
    many iterations in LOG_DIR/student (both stages in one command; an interrupted student
    goes on with --resume LOG_DIR/student)"""
    student_actor: str = "gru"
    """--student-iterations: the student's model (mlp, gru, lstm)"""
    student_num_envs: int = 0
    """--student-iterations: the student's number of envs (0: the teacher's --num-envs; the
    residual recipe's default: half of it; its settled-start pool scales with it, and with
    --distill-levels each env starts on the level of one of its teacher's on the same kind
    of tile)"""
    student_nominal_physics_iterations: int | None = None
    """--student-iterations: the student's last N iterations draw the model's physics (as
    --nominal-physics-iterations does the teacher's, --nominal-physics-keep's ranges kept);
    None: the teacher's resolved --nominal-physics-iterations (residual_walk's recipe: 140
    of the student's 160, from its iteration 20; adaptive_gait's: none; docs/learning.md)"""
    distill_levels: bool = False
    """--distill, --student-iterations: the student's curriculum starts where its teacher's
    checkpoint left it (each env on its teacher's terrain level; with another number of
    envs, on the level of one of its envs on the same kind of tile) instead of at the
    start level"""
    finetune_iterations: int = 0
    """--student-iterations or --distill: when the student is distilled, train it on with
    PPO for this many iterations in LOG_DIR/finetune (LOG_DIR: the teacher's with
    --student-iterations): the student as the actor from the distillation's last
    checkpoint and curriculum levels, its teacher's critic and action std, the student's
    world, reward and pieces, --finetune-learning-rate, no symmetry; an interrupted
    fine-tune goes on with --resume LOG_DIR/finetune (docs/learning.md)"""
    finetune_learning_rate: float = 1e-4
    """--finetune-iterations: the fine-tune's first Adam step (adaptive on KL from there)"""
    finetune_num_envs: int = 0
    """--finetune-iterations: the fine-tune's number of envs (0: the student's --num-envs;
    its settled-start pool scales with it, and each env starts on the level of one of the
    student's on the same kind of tile)"""

    def __post_init__(self) -> None:
        require_choice(self, "actor", ACTORS)
        require_choice(self, "student_actor", ACTORS)
        if self.critic not in ("", *ACTORS):
            raise ValueError(f"--critic must be one of {', '.join(ACTORS)} (or '' for the "
                             f"actor's), got {self.critic!r}")  # fmt: skip
        require_at_least(self, 1, "rnn_hidden_dim", "gradient_length")
        stage = tuple(name for name in ("nominal_physics_iterations",
                                        "student_nominal_physics_iterations")
                      if getattr(self, name) is not None)  # fmt: skip
        require_at_least(self, 0, "student_iterations", "student_num_envs", "finetune_iterations",
                         "finetune_num_envs", *stage)  # fmt: skip
        if self.nominal_physics_entropy_coef is not None:
            require_at_least(self, 0, "nominal_physics_entropy_coef")
        require_at_most(self, MAX_WIDTH, "rnn_hidden_dim")
        require_at_most(self, MAX_ITERATIONS, "gradient_length", "student_iterations",
                        "finetune_iterations", *stage)  # fmt: skip
        require_at_most(self, MAX_ENVS, "student_num_envs", "finetune_num_envs")
        for name in self.nominal_physics_keep:
            if name not in PHYSICS_RANGES:
                raise ValueError(f"--nominal-physics-keep names ranges of --env.randomization "
                                 f"({', '.join(PHYSICS_RANGES)}), got {name!r}")  # fmt: skip
        if self.late_iterations is not None:
            require_at_least(self, 0, "late_iterations")
            require_at_most(self, MAX_ITERATIONS, "late_iterations")
        late = [name for name in LATE_VALUES if getattr(self, name) is not None]
        require_positive(self, *(n for n in late if n in ("late_sigma", "late_clearance_target")))
        require_at_least(self, 0, *late)
        if self.late_iterations is not None and bool(late) != bool(self.late_iterations):
            raise ValueError(
                f"--late-iterations {self.late_iterations} and the stage's values go together "
                f"({', '.join(map(flag, LATE_VALUES))}), got "
                f"{', '.join(show_flag(n, getattr(self, n)) for n in late) or 'none'}"
            )
        require_at_least(self, 0, "flat_from")
        require_at_most(self, MAX_ITERATIONS, "flat_from")
        if self.flat_until is not None:
            require_in(self, "flat_until", self.flat_from + 1, MAX_ITERATIONS)
        kinds = self.flat_kinds
        if not set(kinds) <= set(KNOWN_KINDS) or len(set(kinds)) != len(kinds):
            raise ValueError(f"{show_flag('flat_kinds', kinds)}: kinds of tile from "
                             f"{', '.join(KNOWN_KINDS)}, each once")  # fmt: skip
        if not kinds and (self.flat_from or self.flat_until is not None):
            window = "flat_from" if self.flat_from else "flat_until"
            raise ValueError(f"{show_flag(window, getattr(self, window))} needs --flat-kinds "
                             f"KIND ...: the kinds of tile the window flattens")  # fmt: skip
        if self.student_iterations and not self.teacher:
            raise ValueError("--student-iterations needs --teacher: the student is distilled "
                             "from the teacher this run trains")  # fmt: skip
        if self.distill_levels and not (self.distill or self.student_iterations):
            raise ValueError("--distill-levels needs --distill or --student-iterations: it "
                             "starts a student on its teacher's terrain levels")  # fmt: skip
        if self.late_iterations and self.distill:
            raise ValueError("--late-iterations changes the reward, which a distilled student "
                             "does not learn from")  # fmt: skip
        if self.warm_start and self.distill:
            raise ValueError("--warm-start and --distill do not go together: a distilled "
                             "student learns from its teacher, from scratch")  # fmt: skip
        for name in ("warm_start_critic", "warm_start_levels"):
            if getattr(self, name) and not self.warm_start:
                raise ValueError(f"{show_flag(name, getattr(self, name))} needs --warm-start: "
                                 "it completes the warm start's checkpoint")  # fmt: skip
        if self.finetune_iterations and not (self.student_iterations or self.distill):
            raise ValueError(f"--finetune-iterations {self.finetune_iterations} needs "
                             "--student-iterations or --distill: it fine-tunes a distilled "
                             "student")  # fmt: skip
        for name in ("student_num_envs", "student_nominal_physics_iterations"):
            if getattr(self, name) and not self.student_iterations:
                raise ValueError(f"{show_flag(name, getattr(self, name))} needs "
                                 "--student-iterations: it sets the student's stage")  # fmt: skip
        require_at_least(self, 0, "distill_smoothness")
        require_at_most(self, MAX_SMOOTHNESS, "distill_smoothness")
        if self.distill_smoothness and not (self.distill or self.student_iterations):
            raise ValueError(f"--distill-smoothness {self.distill_smoothness} needs --distill or "
                             "--student-iterations: it shapes a distilled student")  # fmt: skip
        require_at_least(self, 0, "lag_smoothness")
        require_at_most(self, MAX_SMOOTHNESS, "lag_smoothness")
        if self.lag_smoothness:  # (a recurrent model's minibatches are padded trajectories)
            other = ("--distill" if self.distill else f"--actor {self.actor}"
                     if self.actor != "mlp" else f"--critic {self.critic_kind}"
                     if self.critic_kind != "mlp" else "")  # fmt: skip
            if other:
                raise ValueError(f"--lag-smoothness {self.lag_smoothness} needs PPO with an MLP "
                                 f"actor and critic, got {other}")  # fmt: skip
        if self.finetune_num_envs and not self.finetune_iterations:
            raise ValueError(f"--finetune-num-envs {self.finetune_num_envs} needs "
                             "--finetune-iterations: it sizes the fine-tune")  # fmt: skip
        obs = self.teacher_obs
        if not obs or not set(obs) <= set(SIMULATOR_PIECES) or len(set(obs)) != len(obs):
            raise ValueError(f"{show_flag('teacher_obs', obs)}: privileged pieces from "
                             f"{', '.join(SIMULATOR_PIECES)}, each once")  # fmt: skip
        if obs != PRIVILEGED_PIECES and not self.teacher:
            raise ValueError(f"{show_flag('teacher_obs', obs)} needs --teacher: they are what "
                             "a teacher's actor reads")  # fmt: skip
        if self.teacher and self.distill:
            raise ValueError("--teacher and --distill do not go together: a teacher is "
                             "trained with PPO, then distilled into a student")  # fmt: skip
        require_at_least(self, 1, "num_steps_per_env", "num_learning_epochs", "num_mini_batches")
        require_at_most(self, MAX_ITERATIONS, "num_steps_per_env", "num_learning_epochs",
                        "num_mini_batches")  # fmt: skip
        require_positive(self, "reward_scale", "learning_rate", "init_noise_std", "clip_param",
                         "finetune_learning_rate")  # fmt: skip
        require_positive(self, "desired_kl", "max_grad_norm")
        require_at_least(self, 0, "entropy_coef")
        require_in(self, "gamma", 0.0, 1.0, low_open=True)
        require_in(self, "lam", 0.0, 1.0)
        if not self.hidden_dims or min(self.hidden_dims) < 1:
            raise ValueError(f"--hidden-dims must be sizes >= 1, got {self.hidden_dims}")
        if len(self.hidden_dims) > MAX_LAYERS or max(self.hidden_dims) > MAX_WIDTH:
            raise ValueError(
                f"--hidden-dims must be at most {MAX_LAYERS} layers of at most {MAX_WIDTH} "
                f"units, got {self.hidden_dims}"
            )

    @property
    def critic_kind(self) -> str:
        """The critic's model (mlp, gru, lstm): --critic, else the actor's."""
        return self.critic or self.actor

    def model(self, output_std: bool = True, kind: str | None = None) -> dict[str, Any]:
        """rsl-rl's config of this run's actor (a student's) model, or of ``kind`` (mlp, gru,
        lstm); ``output_std``: with its Gaussian output (a stochastic policy)."""
        kind = kind or self.actor
        model: dict[str, Any] = {
            "class_name": "MLPModel" if kind == "mlp" else "RNNModel",
            "hidden_dims": list(self.hidden_dims),
            "activation": "elu",
            "obs_normalization": True,
        }
        if kind != "mlp":
            model |= {"rnn_type": kind, "rnn_hidden_dim": self.rnn_hidden_dim,
                      "rnn_num_layers": 1}  # fmt: skip
        if output_std:
            model["distribution_cfg"] = {
                "class_name": "GaussianDistribution",
                "init_std": self.init_noise_std,
            }
        return model

    def to_rsl_rl(self, save_interval: int, teacher: TrainConfig | None = None) -> dict[str, Any]:
        """rsl-rl-lib 5.x's training config (a fresh dict: its algorithms pop keys from it):
        PPO, or with ``teacher`` (the teacher run's config) Distillation into this run's
        actor as the student."""
        common = {"num_steps_per_env": self.num_steps_per_env, "save_interval": save_interval}
        if teacher is not None:
            return common | {
                "obs_groups": {"student": ["policy"], "teacher": ["teacher"]},
                "algorithm": {
                    "class_name": "rwalk.rl.distillation:SmoothDistillation",
                    "smoothness": self.distill_smoothness,
                    "num_learning_epochs": self.num_learning_epochs,
                    "gradient_length": self.gradient_length,
                    "learning_rate": self.learning_rate,
                    "max_grad_norm": self.max_grad_norm,
                    "loss_type": "mse",
                },
                "student": self.model(),
                "teacher": teacher.model(),
            }
        algorithm = {
            "class_name": "PPO",
            "learning_rate": self.learning_rate,
            "entropy_coef": self.entropy_coef,
            "num_learning_epochs": self.num_learning_epochs,
            "num_mini_batches": self.num_mini_batches,
            "gamma": self.gamma,
            "lam": self.lam,
            "schedule": "adaptive",
            "desired_kl": self.desired_kl,
            "clip_param": self.clip_param,
            "value_loss_coef": 1.0,
            "use_clipped_value_loss": False,
            "max_grad_norm": self.max_grad_norm,
        }
        if self.lag_smoothness:
            algorithm |= {"class_name": "rwalk.rl.ppo:LagSmoothedPPO",
                          "lag_smoothness": self.lag_smoothness}  # fmt: skip
        if mirrored(self):
            algorithm["symmetry_cfg"] = {
                "use_data_augmentation": True,
                "use_mirror_loss": False,
                "data_augmentation_func": "rwalk.rl.symmetry:augment",
            }
        return common | {
            "obs_groups": {"actor": ["policy"], "critic": ["critic"]},
            "algorithm": algorithm,
            "actor": self.model(),
            "critic": self.model(output_std=False, kind=self.critic_kind),
        }


def mirrored(train) -> bool:
    """Whether a training (its ``TrainConfig``, or the ``Training``) augments with mirrors:
    --symmetry, where rsl-rl allows it (PPO with an MLP actor and critic)."""
    train = getattr(train, "train", train)
    mlp = train.actor == "mlp" and train.critic_kind == "mlp"
    return train.symmetry and mlp and not train.distill


def symmetry_refusal(train) -> str | None:
    """Why an explicit --symmetry cannot apply to ``train`` (its ``TrainConfig``, or the
    ``Training``; None: it can)."""
    train = getattr(train, "train", train)
    if not train.symmetry or mirrored(train):
        return None
    if train.distill:
        return ("--symmetry and --distill do not go together (rsl-rl's Distillation refuses "
                "the symmetry extension)")  # fmt: skip
    return (f"--symmetry needs --actor mlp and an MLP critic (rsl-rl's symmetry augmentation "
            f"refuses recurrent models), got --actor {train.actor} "
            f"--critic {train.critic_kind}")  # fmt: skip


#: How rwalk-train trains a task (Preset.recipe).
RECIPES = ("precise", "plain")


@dataclass(frozen=True)
class Preset:
    """Where a training's configs start from: its task and world
    (``rwalk.presets.training_env``). Every other flag then sets one field of them."""

    task: str = "residual_walk"
    """task: residual_walk or adaptive_gait"""
    robust: bool = True
    """train for worlds never seen: per-env terrain levels with their curriculum, physics
    randomisation, pushes, observation noise and a privileged critic (--no-robust: one rough
    world, --env.terrain-scale its roughness)"""
    costs: bool = False
    """add the gait costs to the reward (--env.costs.*: swing clearance below a target above
    the ground, feet slipping, servo power; rwalk.rewards.GaitCosts); --recipe precise
    adds them to either task's robust training either way"""
    settle_pool_fraction: float = SETTLE_POOL_FRACTION
    """settled starts kept ready, as a fraction of --num-envs (--env.settle-pool: a count)"""
    recipe: str = "precise"
    """how the task trains in the robust world: precise (the task's default, Task.recipe,
    each of its values a flag that may be set; residual_walk: a teacher that reads the
    drawn physics and the ground under its feet, then its blind GRU student, with the
    gait costs, the speed kernel, wider servo and latency ranges, actions of +-30 mm and
    three times the noise on the forward speed it reads, docs/learning.md; adaptive_gait:
    the gait the command asks for within narrowed bounds, commands of 0.03-0.27 m/s, the
    gait costs and the speed kernel, a teacher that reads the ground and its blind GRU
    student, docs/adaptive.md) or plain (PPO alone, the late kernel); --no-robust trains
    plain"""

    def __post_init__(self) -> None:
        get_task(self.task)  # ValueError listing the known tasks
        require_in(self, "settle_pool_fraction", 0.0, 1.0, low_open=True)
        require_choice(self, "recipe", RECIPES)

    @property
    def own_recipe(self):
        """The task's ``Recipe`` where this preset trains with it, else None."""
        precise = self.recipe == "precise" and self.robust
        return get_task(self.task).recipe if precise else None

    def env(self, num_envs: int) -> EnvConfig:
        """The task's training env for ``num_envs`` envs in this preset's world (and its
        recipe's, ``own_recipe``)."""
        env = training_env(self.task, num_envs=num_envs, robust=self.robust, costs=self.costs,
                           settle_pool_fraction=self.settle_pool_fraction)  # fmt: skip
        recipe = self.own_recipe
        return env if recipe is None else recipe.env(env)


Env = TypeVar("Env", bound=EnvConfig)


@dataclass(frozen=True)
class TrainingBase(Generic[Env]):
    """What every trainer's training has: the envs' config, the preset it started from
    and the count of envs (a trainer adds its algorithm as ``train`` and its ``run``)."""

    env: Env
    """The envs: the task's EnvConfig."""
    preset: OmitArgPrefixes[Preset] = field(default_factory=Preset)
    """The task and world the configs started from."""
    num_envs: int = 1024
    """parallel envs (under torchrun: per rank; with collectors: per worker)"""

    def __post_init__(self) -> None:
        require_at_least(self, 1, "num_envs")
        require_at_most(self, MAX_ENVS, "num_envs")
        kind = get_task(self.task).config_type
        if type(self.env) is not kind:
            raise ValueError(f"the {self.task} task's env is a {kind.__name__}, got a "
                             f"{type(self.env).__name__}")  # fmt: skip

    @property
    def task(self) -> str:
        """The task's registry name."""
        return self.preset.task

    def env_config(self, threads: int | None = None) -> EnvConfig:
        """The envs' config, its physics on ``threads`` threads (None: the run's --threads,
        where set, else ``env.num_threads``)."""
        threads = self.run.threads if threads is None else threads  # type: ignore[attr-defined]
        return dataclasses.replace(self.env, num_threads=threads or self.env.num_threads)

    def resolved(self):
        """This training with every rule written out as its record keeps it (here: as it
        is; ``Training`` writes out its observation groups)."""
        return self


@dataclass(frozen=True)
class Training(TrainingBase[Env]):
    """An rwalk-train run: every field is a command-line flag, checked on creation by the
    config it belongs to; config.json holds it, resolved (``rwalk.rl.record``)."""

    train: OmitArgPrefixes[TrainConfig] = field(default_factory=TrainConfig)
    """rsl-rl's algorithm, models and stages."""
    run: OmitArgPrefixes[RunConfig] = field(default_factory=RunConfig)
    """Where the run writes and how long it runs."""

    def __post_init__(self) -> None:
        super().__post_init__()
        sizes = {
            "num_envs": self.num_envs,
            "student_num_envs": self.train.student_num_envs,
            "finetune_num_envs": self.train.finetune_num_envs,
        }
        for name, envs in sizes.items():
            frames = envs * self.train.num_steps_per_env
            if envs and self.train.num_mini_batches > frames:  # 0: no stage of its own size
                raise ValueError(f"--num-mini-batches must be <= {flag(name)} * "
                                 f"--num-steps-per-env = {frames}, got "
                                 f"{self.train.num_mini_batches}")  # fmt: skip
        if self.train.late_iterations is not None:  # else resolved() writes it out, then
            late_reward(self.train, self.env)  # checks: refused here, not at the stage's start
        kinds = self.env.terrain_levels.kinds if self.env.terrain_levels is not None else ()
        if not set(self.train.flat_kinds) <= set(kinds):
            raise ValueError(f"{show_flag('flat_kinds', self.train.flat_kinds)}: this "
                             f"training's map has the kinds {' '.join(kinds) or 'none'} "
                             f"(--terrain-kinds)")  # fmt: skip
        if self.train.flat_kinds and self.train.flat_from >= self.run.max_iterations:
            raise ValueError(f"--flat-from {self.train.flat_from}: the run ends before, at "
                             f"--max-iterations {self.run.max_iterations}")  # fmt: skip
        task = get_task(self.task)
        known = piece_catalog(task.pieces(), task.observation)
        for name in ("policy_obs", "critic_obs"):
            unknown = [p for p in getattr(self.train, name) if p not in known]
            if unknown:
                raise ValueError(f"{flag(name)}: {self.task} has no piece {unknown[0]!r}; "
                                 f"choose from {tuple(known)}")  # fmt: skip

    def resolved(self) -> Training:
        """This training with its observation groups written out (``resolved``)."""
        return resolved(self)


def observation_groups(task, env: EnvConfig, train: TrainConfig | None = None
                       ) -> dict[str, tuple[str, ...]]:  # fmt: skip
    """The pieces of the policy and the critic of a training (the one rule).

    The policy reads ``train.policy_obs``, else the spec observation and the task's
    extra pieces (on a terrain-levels map its observation counts the torso's x, y from
    the episode's start: where it is would tell its level; the piece ``command`` only
    when the envs draw commands); a teacher's (``train.teacher``) also reads its
    privileged pieces (``train.teacher_obs``). The critic reads ``train.critic_obs``, else
    the policy's pieces plus the privileged ones (PRIVILEGED_PIECES: the drawn physics,
    the ground around the feet) when the world varies (``EnvConfig.varies``), a
    teacher's its own.

    Args:
        task: the task (class or instance) whose pieces the groups are.
        env: the training's envs (or ``rwalk.rl.legacy.TrainingEnv``, an older run's flags).
        train: the training's config (None: the defaults).
    """
    if hasattr(env, "config") and not isinstance(env, EnvConfig):  # a TrainingEnv
        env = env.config()
    train = train or TrainConfig()
    policy_obs = train.policy_obs
    if not policy_obs:
        observation = "observation" if env.terrain_levels is None else "observation_from_start"
        extras = [name for name in task.extras_for(env) if name != "command" or env.command_range]
        policy_obs = (observation, *extras)
    privileged = train.teacher_obs if train.teacher else PRIVILEGED_PIECES if env.varies else ()
    if train.teacher:
        policy_obs = (*policy_obs, *(name for name in privileged if name not in policy_obs))
    critic = train.critic_obs or (*policy_obs, *(n for n in privileged if n not in policy_obs))
    return {"policy": tuple(policy_obs), "critic": tuple(critic)}


def resolved(training: Training) -> Training:
    """``training`` with its rules written out: its groups (``observation_groups``) and
    its stage at the model's physics (``TrainConfig.nominal_physics_iterations``); what
    its record keeps, so that a later change of a rule never changes how the run is read."""
    task = get_task(training.task)
    groups = observation_groups(task, training.env, training.train)
    stage = training.train.nominal_physics_iterations
    if stage is None:
        share = task.nominal_physics_share if training.env.randomization is not None else 0
        stage = round(share * training.run.max_iterations)
    # no stage (the teacher's nor its student's) keeps nothing
    students = training.train.student_nominal_physics_iterations
    keep = training.train.nominal_physics_keep if stage or students else ()
    # a stage's entropy bonus is PPO's: none without a stage, none for a distilled student
    ppo = stage and not training.train.distill
    entropy = training.train.nominal_physics_entropy_coef if ppo else None
    env, late = _late_stage(task, training)
    train = dataclasses.replace(
        training.train, policy_obs=groups["policy"], critic_obs=groups["critic"],
        nominal_physics_iterations=stage, nominal_physics_keep=keep,
        nominal_physics_entropy_coef=entropy, **late,
    )  # fmt: skip
    return dataclasses.replace(training, env=env, train=train)


def _late_stage(task, training: Training) -> tuple[EnvConfig, dict[str, Any]]:
    """The env and the late fields of ``training`` with its late stage written out: as
    given, or (--late-iterations None) the task's own where the physics is randomised
    (``Task.late_stage``, the late flags given replacing its values; where it moves the
    speed kernel of an env without one, the kernel's terms are added at weight 0,
    ``Shaping()``: exact zeros before the stage)."""
    train, env = training.train, training.env
    if train.late_iterations is not None:
        return env, {}
    given = {name: value for name in LATE_VALUES if (value := getattr(train, name)) is not None}
    own = task.late_stage if env.randomization is not None and not train.distill else None
    share, values = own or (0.0, {})
    late = round(share * training.run.max_iterations)
    if not late:
        if given:
            name, value = next(iter(given.items()))
            raise ValueError(f"{show_flag(name, value)} needs --late-iterations N: this "
                             f"training has no late stage of its own")  # fmt: skip
        return env, {"late_iterations": 0}
    values = values | given
    if env.shaping is None and any(LATE_VALUES[name][0] == "shaping" for name in values):
        env = dataclasses.replace(env, shaping=Shaping())
    return env, {"late_iterations": late, **values}


def late_reward(train: TrainConfig, env: EnvConfig) -> dict[str, Any]:
    """The reward's parts of ``env`` that --late-iterations' stage sets: {"shaping": its
    Shaping, "costs": its GaitCosts}, each with the values of ``train``'s late flags.

    Raises:
        ValueError: naming the flag, where ``env`` has not the part or the value is bad.
    """
    parts: dict[str, Any] = {}
    for name, (part, field_name) in LATE_VALUES.items():
        value = getattr(train, name)
        if value is None:
            continue
        if getattr(env, part) is None:
            raise ValueError(f"{show_flag(name, value)} changes --env.{part}, which this "
                             f"training has not (set one of its flags)")  # fmt: skip
        try:
            parts[part] = dataclasses.replace(parts.get(part, getattr(env, part)),
                                              **{field_name: value})  # fmt: skip
            dataclasses.replace(env, **{part: parts[part]})  # with the env's speeds
        except ValueError as error:
            raise ValueError(f"{show_flag(name, value)}: {error}") from None
    return parts


def student_training(teacher: Training) -> Training:
    """The student stage of ``teacher`` (a run with --student-iterations): distil its
    LOG_DIR's teacher into a --student-actor model in LOG_DIR/student for
    --student-iterations iterations, in the teacher's world, blind (the teacher's policy
    pieces but the privileged ones), with the teacher's PPO settings and --overwrite, on
    --student-num-envs envs (its settled-start pool in the teacher's proportion)."""
    blind = tuple(name for name in teacher.train.policy_obs if name not in SIMULATOR_PIECES)
    train = dataclasses.replace(
        teacher.train, teacher=False, teacher_obs=PRIVILEGED_PIECES, distill=teacher.run.log_dir,
        warm_start="", policy_obs=blind,
        actor=teacher.train.student_actor, student_iterations=0, student_num_envs=0,
        lag_smoothness=0.0,
        nominal_physics_iterations=_student_stage(teacher.train),
        student_nominal_physics_iterations=None,
        symmetry=False, critic_obs=(), critic="", warm_start_critic="", warm_start_levels=False,
        late_iterations=0, flat_kinds=(), flat_from=0, flat_until=None,
        **dict.fromkeys(LATE_VALUES),
    )  # fmt: skip
    run = dataclasses.replace(
        teacher.run, resume="", max_iterations=teacher.train.student_iterations,
        log_dir=str(Path(teacher.run.log_dir) / "student"),
        run_name=f"{teacher.run.run_name or Path(teacher.run.log_dir).name}-student",
    )  # fmt: skip
    envs = teacher.train.student_num_envs or teacher.num_envs
    return resolved(dataclasses.replace(teacher, train=train, run=run, num_envs=envs,
                                        env=_settle_pool_for(teacher, envs)))  # fmt: skip


def _student_stage(teacher: TrainConfig) -> int:
    """The one command's student's iterations at the model's physics: its own
    --student-nominal-physics-iterations, else its (resolved) teacher's count."""
    own = teacher.student_nominal_physics_iterations
    return teacher.nominal_physics_iterations if own is None else own


def _settle_pool_for(training: Training, envs: int) -> EnvConfig:
    """``training``'s env with its settled-start pool scaled from its --num-envs to
    ``envs`` (at least one start where it has a pool)."""
    pool = training.env.settle_pool
    if pool:
        pool = min(MAX_ENVS, max(1, round(pool * envs / training.num_envs)))
    return dataclasses.replace(training.env, settle_pool=pool)


def finetune_training(student: Training, checkpoint: Path, teacher: Path,
                      teacher_args: Training) -> Training:  # fmt: skip
    """The fine-tune stage of ``student`` (a distillation with --finetune-iterations): PPO on
    its ``checkpoint`` in LOG_DIR/finetune (LOG_DIR: the one command's, where its teacher
    is; else the student's own folder) for --finetune-iterations iterations, the student
    as the actor with its curriculum levels, the critic and action std of its ``teacher``
    checkpoint (whose run is ``teacher_args``), in the student's world with its reward and
    pieces, at --finetune-learning-rate, without symmetry or late stages, on
    --finetune-num-envs envs (its settled-start pool in the student's proportion)."""
    train = dataclasses.replace(
        student.train, distill="", distill_levels=False, distill_smoothness=0.0,
        lag_smoothness=0.0,
        finetune_iterations=0, finetune_num_envs=0,
        warm_start=str(checkpoint), warm_start_critic=str(teacher), warm_start_levels=True,
        critic=teacher_args.train.critic_kind, critic_obs=teacher_args.train.critic_obs,
        learning_rate=student.train.finetune_learning_rate, symmetry=False,
        nominal_physics_iterations=0, nominal_physics_keep=(), late_iterations=0,
    )  # fmt: skip
    log_dir, teacher_dir = Path(student.run.log_dir), Path(student.train.distill)
    home = teacher_dir if log_dir == teacher_dir / "student" else log_dir  # the one command's
    run = dataclasses.replace(
        student.run, resume="", max_iterations=student.train.finetune_iterations,
        log_dir=str(home / "finetune"), run_name=f"{student.run.run_name or home.name}-finetune",
    )  # fmt: skip
    envs = student.train.finetune_num_envs or student.num_envs
    return resolved(dataclasses.replace(student, train=train, run=run, num_envs=envs,
                                        env=_settle_pool_for(student, envs)))  # fmt: skip


#: TrainConfig's fields whose default changed after runs were recorded without them (a
#: schema-2 record written before the field, every schema-1 record): the value such a
#: run trained with.
PREDATING = {"nominal_physics_iterations": 0, "late_iterations": 0}


#: Fields that may differ from the run's own on --resume: the run's settings (where it
#: writes, how long, threads, seeds, logging) and how many envs step. Every other field
#: (task, world, algorithm, models, observation pieces) comes from the run's config.json.
RESUME_MAY_CHANGE = ("run", "num_envs")


class ResumeConflict(ValueError):
    """A flag given on --resume that contradicts the resumed run's own."""


def leaves(value: Any, prefix: str = "") -> dict[str, Any]:
    """Every leaf field of a config, by its dotted path (``env.costs.clearance``); a part
    that is None is one leaf."""
    if not dataclasses.is_dataclass(value):
        return {prefix[:-1]: value}
    out: dict[str, Any] = {}
    for f in dataclasses.fields(value):
        out |= leaves(getattr(value, f.name), f"{prefix}{f.name}.")
    return out


def flag_of(path: str) -> str:
    """The flag of a leaf's dotted path: the parts typed ``OmitArgPrefixes`` (preset,
    train, run) give top-level flags (``train.hidden_dims`` -> ``--hidden-dims``)."""
    head, _, tail = path.partition(".")
    return flag(tail if head in ("preset", "train", "run") else path)


def resume_conflict(given: Training, saved: Training, path: Path, config: Path) -> None:
    """Refuse a resumed run's command line that sets a field (outside
    ``RESUME_MAY_CHANGE``) to another value than its run's own.

    Args:
        given: what the command line made, parsed from ``saved``'s values.
        path, config: the resumed checkpoint and its run's config.json (for messages).

    Raises:
        ResumeConflict: naming the flag and both values.
    """
    mine, theirs = leaves(given), leaves(saved)
    for name, value in mine.items():
        if name.split(".")[0] in RESUME_MAY_CHANGE or theirs.get(name) == value:
            continue
        option = flag_of(name)[2:]
        own = show_flag(option, theirs.get(name))
        raise ResumeConflict(
            f"--resume {path}: its run trained with {own} (its {config}), not "
            f"{show_flag(option, value)}; pass {own} to resume it, or leave {flag(option)} out "
            f"(on --resume only the run's settings and --num-envs may change)"
        )


#: Older names of this module, now in ``rwalk.rl.legacy`` (schema-1 flags) and
#: ``rwalk.rl.record`` (reading a run's config.json).
_MOVED = {
    "TrainArgs": "rwalk.rl.legacy", "RETIRED_FLAGS": "rwalk.rl.legacy",
    "ConfigError": "rwalk.rl.record", "MAX_CONFIG_BYTES": "rwalk.rl.record",
    "load_saved_args": "rwalk.rl.record",
}  # fmt: skip


def __getattr__(name: str):
    if name in _MOVED:
        import importlib

        return getattr(importlib.import_module(_MOVED[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
