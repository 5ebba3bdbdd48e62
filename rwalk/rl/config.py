"""The training's configs: the run, and rsl-rl's algorithm and models, as dataclasses.

``RunConfig`` says where a training writes and how long it runs; ``TrainConfig``
holds PPO's settings, the models and what the policy observes, converted to
rsl-rl's dict at the boundary (``to_rsl_rl``: a fresh dict, since rsl-rl's PPO
pops keys from the dict it is given). With ``rwalk.presets.TrainingEnv`` they are
the source of truth of a training: ``rwalk-train``'s flags map one to one onto
their fields, and ``config.json`` stores them.

``observation_groups`` is the one rule for which pieces the policy and the
critic read; training, evaluation and export all take it from here.
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rwalk.cli import (
    combine,
    flag,
    from_fields,
    require_at_least,
    require_at_most,
    require_in,
    require_positive,
    show_flag,
)
from rwalk.config import MAX_THREADS
from rwalk.observations import PRIVILEGED_PIECES, piece_catalog
from rwalk.presets import TrainingEnv
from rwalk.rl.distributed import DEFAULT_TIMEOUT_S
from rwalk.rng import SEED_LIMIT
from rwalk.tasks.base import Task
from rwalk.tasks.registry import get_task

#: The actor's (or student's) models: an MLP, or a recurrent layer before the MLP.
ACTORS = ("mlp", "gru", "lstm")
#: Most iterations of a run, and most of the counts per iteration.
MAX_ITERATIONS = 10**9
#: Most layers, and most units in a layer, of the actor's and the critic's MLPs.
MAX_LAYERS = 8
MAX_WIDTH = 4096
#: Largest config.json read (a run's is a few KB).
MAX_CONFIG_BYTES = 1 << 20
#: Flags of older versions that a saved config.json may hold: dropped when it is read.
RETIRED_FLAGS = ("curriculum_iterations",)


class ConfigError(ValueError):
    """A run's config.json that cannot be read as its flags; the message names the file
    and the field."""


#: rwalk-train's --logger choices (rsl-rl's writers).
LOGGERS = ("tensorboard", "wandb")


@dataclass(frozen=True)
class RunConfig:
    """Where a training writes, from what it goes on, and how long it runs."""

    log_dir: str = "logs/rwalk"
    """output folder of this run"""
    seed: int = 0
    """seed of the envs and of torch (under torchrun, rank r seeds its envs with seed + r *
    (num_envs + its settled-start pool) and torch with seed + r)"""
    resume: str = ""
    """continue from this checkpoint file, or from the newest checkpoint that loads in this
    run folder"""
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
        require_at_least(self, 1, "max_iterations", "save_interval")
        require_at_least(self, 0, "threads", "seed")
        require_at_most(self, SEED_LIMIT - 1, "seed")
        require_at_most(self, MAX_ITERATIONS, "max_iterations", "save_interval")
        require_at_most(self, MAX_THREADS, "threads")
        require_positive(self, "dist_timeout")
        require_positive(self, "max_minutes", finite=False)
        if not self.log_dir.strip():
            raise ValueError("--log-dir must name a folder, got ''")
        if self.logger not in LOGGERS:
            raise ValueError(f"--logger must be one of {', '.join(LOGGERS)}, got {self.logger!r}")
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
    policy_obs: tuple[str, ...] = field(default=(), metadata={"item": str})
    """observation pieces the policy sees (none: the observation, phase, lateral_offset and
    the task's command)"""
    actor: str = "mlp"
    """the actor's (a student's) model: mlp, or a recurrent gru or lstm before the MLP layers
    (PPO then trains on whole trajectories; the critic is of the same kind)"""
    rnn_hidden_dim: int = 128
    """--actor gru/lstm: units of the recurrent layer"""
    teacher: bool = False
    """train a teacher: the actor also reads the privileged pieces (the drawn physics, the
    ground around the feet), which only a simulation has; distil it with --distill"""
    distill: str = ""
    """train a blind student against this frozen teacher checkpoint, or the newest in this
    run folder (of an rwalk-train --teacher run), with rsl-rl's Distillation: the student
    reads the policy's pieces (with their noise)"""
    gradient_length: int = 15
    """--distill: steps whose losses add up before each gradient step (a recurrent student
    learns through them)"""
    symmetry: bool = True
    """augment PPO's minibatches with the left-right mirrored states and actions (rsl-rl's
    symmetry augmentation) where rsl-rl allows it: PPO with an MLP actor (recurrent actors
    and distilled students train without it; docs/learning.md)"""
    student_iterations: int = 0
    """with --teacher: when the teacher is trained, distil it into a blind student for this
    many iterations in LOG_DIR/student (both stages in one command; an interrupted student
    goes on with --resume LOG_DIR/student)"""
    student_actor: str = "gru"
    """--student-iterations: the student's model (mlp, gru, lstm)"""

    def __post_init__(self) -> None:
        for name in ("actor", "student_actor"):
            if getattr(self, name) not in ACTORS:
                raise ValueError(f"{flag(name)} must be one of {', '.join(ACTORS)}, got "
                                 f"{getattr(self, name)!r}")  # fmt: skip
        require_at_least(self, 1, "rnn_hidden_dim", "gradient_length")
        require_at_least(self, 0, "student_iterations")
        require_at_most(self, MAX_WIDTH, "rnn_hidden_dim")
        require_at_most(self, MAX_ITERATIONS, "gradient_length", "student_iterations")
        if self.student_iterations and not self.teacher:
            raise ValueError("--student-iterations needs --teacher: the student is distilled "
                             "from the teacher this run trains")  # fmt: skip
        if self.teacher and self.distill:
            raise ValueError("--teacher and --distill do not go together: a teacher is "
                             "trained with PPO, then distilled into a student")  # fmt: skip
        require_at_least(self, 1, "num_steps_per_env", "num_learning_epochs", "num_mini_batches")
        require_at_most(self, MAX_ITERATIONS, "num_steps_per_env", "num_learning_epochs",
                        "num_mini_batches")  # fmt: skip
        require_positive(self, "reward_scale", "learning_rate", "init_noise_std", "clip_param")
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

    def model(self, output_std: bool = True) -> dict[str, Any]:
        """rsl-rl's config of this run's actor (a student's) model; ``output_std``: with its
        Gaussian output (a stochastic policy)."""
        model: dict[str, Any] = {
            "class_name": "MLPModel" if self.actor == "mlp" else "RNNModel",
            "hidden_dims": list(self.hidden_dims),
            "activation": "elu",
            "obs_normalization": True,
        }
        if self.actor != "mlp":
            model |= {"rnn_type": self.actor, "rnn_hidden_dim": self.rnn_hidden_dim,
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
                    "class_name": "Distillation",
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
            "critic": self.model(output_std=False),
        }


def mirrored(train) -> bool:
    """Whether a training (``TrainConfig`` or rwalk-train's flags) augments with mirrors:
    --symmetry, where rsl-rl allows it (PPO with an MLP actor)."""
    return train.symmetry and train.actor == "mlp" and not train.distill


def symmetry_refusal(train) -> str | None:
    """Why an explicit --symmetry cannot apply to ``train`` (None: it can)."""
    if not train.symmetry or mirrored(train):
        return None
    if train.distill:
        return ("--symmetry and --distill do not go together (rsl-rl's Distillation refuses "
                "the symmetry extension)")  # fmt: skip
    return (f"--symmetry needs --actor mlp (rsl-rl's symmetry augmentation refuses recurrent "
            f"models), got --actor {train.actor}")  # fmt: skip


def observation_groups(
    task: Task, env: TrainingEnv, train: TrainConfig | None = None
) -> dict[str, tuple[str, ...]]:
    """The pieces of the policy and the critic of a training (the one rule).

    The policy reads ``train.policy_obs``, else the spec observation and the task's
    extra pieces (a robust run's observation counts the torso's x, y from the episode's
    start: on the terrain-levels map, where it is would tell its level; the piece
    ``command`` only when the envs draw commands); a teacher's (``train.teacher``) also
    reads the privileged pieces. The critic reads the policy's pieces, plus the
    privileged ones (the drawn physics, the ground around the feet) when the training's
    world varies.

    Args:
        task: the task of the envs the groups are read from (its ``extras`` decide the
            default pieces).
        env: the training's envs.
        train: the training's config (None: the defaults).
    """
    train = train or TrainConfig()
    policy_obs = train.policy_obs
    if not policy_obs:
        observation = "observation_from_start" if env.robust else "observation"
        extras = [name for name in task.extras() if name != "command" or env.command_range]
        policy_obs = (observation, *extras)
    privileged = PRIVILEGED_PIECES if env.robust or train.teacher else ()
    if train.teacher:
        policy_obs = (*policy_obs, *(name for name in privileged if name not in policy_obs))
    critic = (*policy_obs, *(name for name in privileged if name not in policy_obs))
    return {"policy": tuple(policy_obs), "critic": critic}


def _from_saved(cls, saved: dict):
    """The flags of a run's config.json (``"args"``), checked field by field
    (``rwalk.cli.from_fields``): flags of older versions (``RETIRED_FLAGS``) are dropped,
    and a run saved before ``robust`` existed trained without it.

    Raises:
        ValueError: naming an unknown key or a bad field.
    """
    return from_fields(cls, {"robust": False} | saved, retired=RETIRED_FLAGS)


def load_saved_args(path: Path, cls: type | None = None, trainer: str = "rsl_rl"):
    """The flags a run stored in its config.json (``path``), as data: the file is read
    only up to MAX_CONFIG_BYTES, parsed as JSON, its "trainer" checked, and each field of
    "args" checked as a field of ``cls`` (default: ``TrainArgs``, rwalk-train's flags).

    Raises:
        FileNotFoundError: naming the file.
        ConfigError: naming the file and what is wrong (size, JSON, another trainer's
            run, the "args" object, an unknown key or a bad field).
    """
    path = Path(path)
    try:
        with path.open("rb") as file:
            data = file.read(MAX_CONFIG_BYTES + 1)
    except FileNotFoundError:
        raise FileNotFoundError(f"{str(path)!r} not found") from None
    except OSError as error:
        raise ConfigError(f"{str(path)!r} cannot be read ({error.strerror})") from None
    if len(data) > MAX_CONFIG_BYTES:
        raise ConfigError(f"{str(path)!r} is larger than {MAX_CONFIG_BYTES} bytes: not a run's")
    try:
        saved = json.loads(data)
    except (ValueError, RecursionError) as error:
        raise ConfigError(f"{str(path)!r} is not JSON ({str(error)[:120]})") from None
    if not isinstance(saved, dict) or not isinstance(saved.get("args"), dict):
        raise ConfigError(f'{str(path)!r} has no object "args" of a run\'s flags')
    written_by = saved.get("trainer", "rsl_rl")  # rwalk-train's from before the key
    if written_by != trainer:
        shown = written_by if isinstance(written_by, str) and len(written_by) <= 32 else "?"
        raise ConfigError(
            f"{str(path)!r} is the config of a run of the {shown!r} trainer, not of {trainer!r}"
        )
    try:
        if cls is None:
            return TrainArgs.from_saved(saved["args"])
        return from_fields(cls, saved["args"], retired=RETIRED_FLAGS)
    except (ValueError, TypeError) as error:
        raise ConfigError(f"{str(path)!r}: args: {error}") from None


#: Flags that may differ from the run's own on --resume: the run's settings (where it
#: writes, how long, threads, seeds, logging) and how many envs step. Every other flag
#: (task, world, algorithm, models, observation pieces) comes from the run's config.json.
RESUME_MAY_CHANGE = (*(f.name for f in dataclasses.fields(RunConfig)), "num_envs")


class ResumeConflict(ValueError):
    """A flag given on --resume that contradicts the resumed run's own."""


def restore_run(args, saved, given: frozenset[str] | None, path: Path, config: Path):
    """``args`` with every flag outside ``RESUME_MAY_CHANGE`` taken from the resumed run's
    ``saved`` flags (of the same class).

    Args:
        given: flags the command line set itself (None: every flag of ``args``).
        path, config: the resumed checkpoint and its run's config.json (for messages).

    Raises:
        ResumeConflict: naming the flag and both values, if ``given`` sets one to another
            value than the run's.
    """
    changes = {}
    for f in dataclasses.fields(args):
        mine, theirs = getattr(args, f.name), getattr(saved, f.name)
        if f.name in RESUME_MAY_CHANGE or mine == theirs:
            continue
        if given is None or f.name in given:
            raise ResumeConflict(
                f"--resume {path}: its run trained with {show_flag(f.name, theirs)} (its "
                f"{config}), not {show_flag(f.name, mine)}; pass {show_flag(f.name, theirs)} "
                f"to resume it, or leave {flag(f.name)} out (on --resume only the flags "
                f"{', '.join(map(flag, RESUME_MAY_CHANGE))} may change)"
            )
        changes[f.name] = theirs
    return dataclasses.replace(args, **changes)


def _check_across(args) -> None:
    """Checks that need fields of several configs: the minibatches fit the rollout, the
    policy's pieces are the task's, and the seeds of every env stay below 2^64."""
    frames = args.num_envs * args.num_steps_per_env
    if args.num_mini_batches > frames:
        raise ValueError(
            f"--num-mini-batches must be <= --num-envs * --num-steps-per-env = {frames}, "
            f"got {args.num_mini_batches}"
        )
    task = get_task(args.task)
    known = piece_catalog(task.pieces(), task.observation)
    unknown = [name for name in args.policy_obs if name not in known]
    if unknown:
        raise ValueError(
            f"--policy-obs: {args.task} has no piece {unknown[0]!r}; choose from {tuple(known)}"
        )


#: rwalk-train's flags: one per field of its three configs (``args.run``, ``args.env``,
#: ``args.train`` rebuild them); config.json stores them under "args".
TrainArgs = combine(
    "Args",
    {"run": RunConfig, "env": TrainingEnv, "train": TrainConfig},
    doc="A training run: every field is a command-line flag (--num-envs, ...), checked on "
    "creation by the config it belongs to (RunConfig, TrainingEnv, TrainConfig).",
    namespace={"from_saved": classmethod(_from_saved), "check": _check_across},
)
