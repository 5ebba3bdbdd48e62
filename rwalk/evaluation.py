"""Evaluation: trained policies and the base gait over fixed-seed, paired episodes.

``evaluate(name, env, seed, policy)`` runs one episode in every env of a batch
(env i starts like a single env seeded seed + i, whatever ran before) and sums
it up as an ``Evaluation``, through the one episode path
(``rwalk.episodes.step``) that training logs with. ``load_policy(checkpoint,
env)`` rebuilds a checkpoint's deterministic policy from its run's record
(config.json, ``rwalk.rl.record``): its models and observation groups as they
trained; ``evaluation_config(checkpoint)`` is the evaluation env its policy acts
in, from that record (``rwalk.presets.evaluation_env``). ``rwalk-play``,
``rwalk-robustness`` and the reports stand on these.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import torch

from rwalk import episodes, presets
from rwalk.config import EnvConfig
from rwalk.constants import OBS_JOINT_VEL
from rwalk.envs.torchrl_env import BatchedEnv
from rwalk.rewards import servo_power
from rwalk.rl.checkpoints import CheckpointError, check_rsl_rl, load_checkpoint, quote, trainer_of
from rwalk.rl.config import Training
from rwalk.rl.record import read_json, read_record
from rwalk.rl.rsl_rl_env import RslRlVecEnv

#: Which command wrote a checkpoint, by its "trainer" key (or its layout, in older files).
TRAINERS = {"rsl_rl": "rwalk-train", "torchrl": "rwalk-train-torchrl"}


@dataclass(frozen=True)
class Evaluation:
    """Per-episode means over the evaluated episodes."""

    name: str
    episodes: int
    mean_return: float
    fall_rate: float
    forward_velocity: float
    """Mean over episodes of the mean torso v_x. m/s."""
    velocity_error: float
    """Mean over episodes of the mean |v_x - v*| per step (what the reward penalises). m/s."""
    velocity_error_se: float
    """Standard error of ``velocity_error`` over the episodes. m/s."""
    contact_score: float
    """Mean over episodes of the per-step contact_pattern term (max 0.2)."""
    mean_length: float
    power: float = math.nan
    """Mean over episodes of the mean servo power, sum over joints of |torque x joint
    speed| (``rwalk.rewards.servo_power``). Watts."""
    cost_of_transport: float = math.nan
    """power / (m g forward_velocity), m the model's mass (a randomised payload not
    counted): energy per unit of weight and distance. Dimensionless."""
    velocity_bias: float = math.nan
    """Mean over episodes of mean v_x - v*: the error's part that the mean speed makes. m/s."""
    velocity_ripple: float = math.nan
    """Mean over episodes of the mean |v_x - its last gait cycle's mean| per step: the
    error's part within the stride (``velocity_error`` is at least about
    ``|velocity_bias|`` and, where the cycle's mean is on target, about this). m/s."""

    @classmethod
    def from_json(cls, data: object) -> Evaluation:
        """An evaluation written by ``dataclasses.asdict`` and read back from JSON, each
        field checked (a name of at most 200 characters, numbers).

        Raises:
            ValueError: naming the field.
        """
        keys = {f.name for f in dataclasses.fields(cls)}
        needed = {f.name for f in dataclasses.fields(cls) if f.default is dataclasses.MISSING}
        if not isinstance(data, dict) or not needed <= set(data) <= keys:
            raise ValueError(
                f"an evaluation must be an object with the keys {sorted(needed)} (and "
                f"optionally {sorted(keys - needed)})"
            )
        name = data["name"]
        if not isinstance(name, str) or len(name) > 200:
            raise ValueError("an evaluation's name must be a text of at most 200 characters")
        numbers = {k: v for k, v in data.items() if k != "name"}
        for key, value in numbers.items():
            if not isinstance(value, (int, float)) or isinstance(value, bool):
                raise ValueError(f"an evaluation's {key} must be a number")
        return cls(**data)


def fall_interval(evaluation: Evaluation) -> tuple[float, float]:
    """Wilson's 95% interval of the fall rate over the evaluation's episodes."""
    n, p, z = evaluation.episodes, evaluation.fall_rate, 1.96
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return max(0.0, centre - half), min(1.0, centre + half)


#: Largest results file (--tables) read back. Bytes.
MAX_RESULTS_BYTES = 16 << 20


def read_results(path: Path) -> object:
    """A results JSON written by a report (``--json``), read as data (at most
    MAX_RESULTS_BYTES).

    Raises:
        ValueError: naming the file, for a file too large or not JSON.
    """
    return read_json(path, MAX_RESULTS_BYTES)


def saved_run(checkpoint: Path) -> Training:
    """The record of ``checkpoint``'s run, read as data from its config.json.

    Raises:
        FileNotFoundError, ConfigError: naming the file (``rwalk.rl.record.read_record``).
    """
    return read_record(Path(checkpoint).parent / "config.json")


def trained_env(checkpoint: Path | None, task: str = "residual_walk") -> EnvConfig:
    """The env config ``checkpoint``'s policy trained in (its record's); without a
    checkpoint (the base gait), ``task``'s defaults."""
    if checkpoint is None:
        return presets.get_task(task).config_type()
    return saved_run(checkpoint).env


def task_of(checkpoint: Path | None, task: str = "residual_walk") -> str:
    """``checkpoint``'s task (its record's); without a checkpoint, ``task``."""
    return task if checkpoint is None else saved_run(checkpoint).task


def evaluation_config(checkpoint: Path | None, task: str = "residual_walk",
                      **changes) -> EnvConfig:  # fmt: skip
    """The evaluation episodes (``presets.EVALUATION``) as ``checkpoint``'s policy acts in
    them (``presets.evaluation_env`` of its record's env and task; the base gait's:
    ``task``'s), with ``changes``."""
    return presets.evaluation_env(trained_env(checkpoint, task), task=task_of(checkpoint, task),
                                  **changes)  # fmt: skip


def evaluation_env(checkpoint: Path | None, num_envs: int, seed: int,
                   task: str = "residual_walk", **changes) -> BatchedEnv:  # fmt: skip
    """``num_envs`` envs (seeded ``seed``) of ``evaluation_config``, of the record's task."""
    config = evaluation_config(checkpoint, task, **changes)
    return BatchedEnv(num_envs, config, seed=seed, task=task_of(checkpoint, task))


def commanded(checkpoint: Path | None) -> bool:
    """Whether ``checkpoint``'s policy trained with commands (it reads the piece command)."""
    return checkpoint is not None and trained_env(checkpoint).command_range is not None


def check_checkpoint(checkpoint: Path) -> None:
    """Fail before any work, naming the file, if ``checkpoint`` cannot be evaluated.

    Raises:
        FileNotFoundError: the checkpoint, or the config.json beside it, is missing.
        ValueError: the file is not a readable checkpoint, another trainer wrote it, or
            its config.json is not a run's (``ConfigError``).
    """
    trainer = trainer_of(load_checkpoint(checkpoint))
    if trainer != "rsl_rl":
        writer = TRAINERS.get(trainer, f"an unknown trainer ({trainer!r})")
        raise ValueError(
            f"checkpoint {str(checkpoint)!r} was written by {writer}; play evaluates rsl-rl "
            f"checkpoints from rwalk-train (model_<it>.pt)"
        )
    config = checkpoint.parent / "config.json"
    if not config.is_file():
        raise FileNotFoundError(
            f"{str(config)!r} not found: play rebuilds the policy of checkpoint "
            f"{str(checkpoint)!r} from the config.json that rwalk-train writes beside it"
        )
    saved_run(checkpoint)  # ConfigError naming the file and the field


def check_policy(checkpoint: Path, task: str | None = None):
    """Fail before any work, naming the file, unless ``checkpoint`` is an rwalk-train
    policy (of ``task``, if given) whose models load from its run's config.json: the
    policy is built once on a one-env core of its task. Returns its run's flags.

    Raises:
        FileNotFoundError, ValueError (``CheckpointError``, ``ConfigError``): naming the
            file, the field, or both tasks.
    """
    check_checkpoint(checkpoint)
    args = saved_run(checkpoint)
    if task is not None and args.task != task:
        raise ValueError(
            f"checkpoint {str(checkpoint)!r} is a {args.task!r} policy, not a {task!r} one"
        )
    load_policy(checkpoint, evaluation_env(checkpoint, 1, seed=0, settle_steps=0))
    return args


class Policy:
    """A trained policy acting on a batched env: ``policy()`` gives the actions of the current
    state (deterministic: the Gaussian's mean), ``policy.reset()`` clears a recurrent
    policy's memory (all envs, or those of a boolean mask) at episodes' starts.

    Args:
        model: the rsl-rl actor (or distilled student), eval mode.
        adapter: the groups it reads (its ``policy`` group).
    """

    def __init__(self, model: torch.nn.Module, adapter: RslRlVecEnv) -> None:
        self.model, self.adapter = model, adapter

    def __call__(self) -> torch.Tensor:
        """Shape: () -> (N, action_dim)."""
        with torch.inference_mode():
            return self.model(self.adapter.get_observations())

    def reset(self, dones: torch.Tensor | None = None) -> None:
        """Forget the memory of every env (None) or of those where ``dones`` is True."""
        self.model.reset(None if dones is None else dones.to(torch.long))

    @property
    def recurrent(self) -> bool:
        return bool(self.model.is_recurrent)


def policy_model(args: Training, adapter: RslRlVecEnv, state: dict) -> torch.nn.Module:
    """The actor (PPO) or student (distillation) of a checkpoint's ``state``, built from its
    run's record ``args`` on the groups of ``adapter``, in eval mode.

    Raises:
        CheckpointError: naming nothing of the file's content, if its model does not have
            the shapes the config builds.
    """
    from rsl_rl.utils import resolve_class

    model_class, model_cfg = resolve_class(args.train.model())
    with contextlib.redirect_stdout(io.StringIO()):
        model = model_class(adapter.get_observations(), {"actor": ["policy"]}, "actor",
                            adapter.num_actions, **model_cfg)  # fmt: skip
    key = "student_state_dict" if "student_state_dict" in state else "actor_state_dict"
    try:
        model.load_state_dict(state[key], strict=True)
    except (RuntimeError, KeyError) as error:
        raise CheckpointError(
            f"the checkpoint's {key} does not fit this run's models (another --hidden-dims, "
            f"--actor, task or observation pieces?): {quote(error)}"
        ) from None
    return model.eval()


def load_policy(checkpoint: Path, env: BatchedEnv) -> Policy:
    """The checkpoint's deterministic policy on ``env`` (a PPO actor or a distilled
    student, MLP or recurrent), rebuilt from its run's record (config.json): its models
    and its policy's pieces. The env must read the action as the run's did (the task's
    ``action_fields``, e.g. the adaptive task's gait_action).

    Raises:
        FileNotFoundError, ValueError (``CheckpointError``, ``ConfigError``): naming the
            file, or the tasks.
    """
    check_checkpoint(checkpoint)
    args = saved_run(checkpoint)
    if args.task != env.core.task.name:
        raise ValueError(
            f"checkpoint {str(checkpoint)!r} is a {args.task!r} policy; the env runs "
            f"{env.core.task.name!r}"
        )
    for name in env.core.task.action_fields:
        mine, theirs = getattr(env.core.config, name), getattr(args.env, name)
        if mine != theirs:
            raise ValueError(
                f"checkpoint {str(checkpoint)!r} trained with --env.{name.replace('_', '-')} "
                f"{theirs}; the env reads its action as {mine!r}"
            )
    adapter = RslRlVecEnv(env, policy_obs=args.train.policy_obs, critic_obs=(),
                          reward_scale=args.train.reward_scale)  # fmt: skip
    state = check_rsl_rl(load_checkpoint(checkpoint), checkpoint)
    try:
        model = policy_model(args, adapter, state)
    except CheckpointError as error:
        raise CheckpointError(f"checkpoint {str(checkpoint)!r}: {error}") from None
    return Policy(model, adapter)


def evaluate(
    name: str,
    env: BatchedEnv,
    seed: int,
    policy: Callable[[], torch.Tensor] | None = None,
    record: Callable[[int], None] | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> Evaluation:
    """Run one episode in every env of ``env`` (reset first) and summarise.

    Args:
        seed: env i starts like a single env seeded seed + i, whatever ran before.
        policy: callable returning (N, action_dim) actions for the current state;
            None = base gait (zero actions).
        record: callable(step) called after every step (e.g. to grab a video frame).
        progress: callable(steps done, max_episode_steps), e.g. a ``Progress``.
    """
    return summarise(name, env, first_episodes(env, seed, policy, record, progress))


@dataclass(frozen=True)
class FirstEpisodes:
    """What each env's first episode did (``first_episodes``)."""

    stats: dict[str, torch.Tensor]
    """``rwalk.episodes``' log of each env's first episode, by key. Shape of each: (N,)."""
    energy: torch.Tensor
    """Servo energy of each first episode, joules / control step. Shape: (N,)."""


def first_episodes(
    env: BatchedEnv,
    seed: int,
    policy: Callable[[], torch.Tensor] | None = None,
    record: Callable[[int], None] | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> FirstEpisodes:
    """Run one episode in every env of ``env`` (reset first; ``evaluate``'s arguments)."""
    core = env.core
    env.set_seed(seed)
    core.reset()
    if policy is not None and hasattr(policy, "reset"):
        policy.reset()  # a recurrent policy remembers nothing of earlier episodes
    n = core.num_envs
    limit = core.config.max_episode_steps
    report = progress or (lambda done, total: None)
    report(0, limit)
    first: dict[str, torch.Tensor] = {}  # each env's first episode (the envs run on after it)
    ended = torch.zeros(n, dtype=torch.bool)
    zeros = torch.zeros(n, core.task.action_dim)
    energy = torch.zeros(n, dtype=torch.float64)  # joules / dt of each first episode
    torque = torch.from_numpy(core.sim.actuator_force)
    with torch.inference_mode():
        for step in range(limit):
            _, end = episodes.step(core, zeros if policy is None else policy(), auto_reset=False)
            power = servo_power(torque, core.obs[:, OBS_JOINT_VEL])
            energy += power.masked_fill(ended, 0.0)
            if end is not None:
                keep = ~ended[end.ids]
                rows = end.ids[keep]
                for key, value in end.stats.items():
                    first.setdefault(key, torch.zeros(n, dtype=value.dtype))[rows] = value[keep]
                ended[end.ids] = True
            if record is not None:
                record(step)
            if bool(ended.all()):
                break
            report(step + 1, limit)
    report(limit, limit)  # every episode has ended
    return FirstEpisodes(first, energy)


def summarise(
    name: str, env: BatchedEnv, run: FirstEpisodes, rows: torch.Tensor | None = None
) -> Evaluation:
    """The ``Evaluation`` of the first episodes of the envs ``rows`` of ``env`` (a
    boolean mask; None: every env)."""
    first = run.stats if rows is None else {k: v[rows] for k, v in run.stats.items()}
    energy = run.energy if rows is None else run.energy[rows]
    n = len(energy)
    length = first["length"]
    errors = first["velocity_error"]
    contact = first.get("sum/contact_pattern", torch.full((n,), math.nan)) / length
    power = float((energy / length).mean())
    forward_velocity = float(first["forward_velocity"].mean())
    model = env.core.sim.model
    weight = float(model.body_mass.sum()) * -float(model.opt.gravity[2])
    return Evaluation(
        name=name,
        episodes=n,
        mean_return=float(first["return"].mean()),
        fall_rate=float(first["terminated"].double().mean()),
        forward_velocity=forward_velocity,
        velocity_error=float(errors.mean()),
        velocity_error_se=float(errors.std() / n**0.5) if n > 1 else 0.0,
        contact_score=float(contact.mean()),
        mean_length=float(length.mean()),
        power=power,
        cost_of_transport=power / (weight * forward_velocity) if forward_velocity > 0 else math.nan,
        velocity_bias=float(first["velocity_bias"].mean()),
        velocity_ripple=float(first["velocity_ripple"].mean()),
    )


def table(rows: list[Evaluation]) -> str:
    """The evaluations as a Markdown table."""
    lines = [
        "| run | episodes | mean return | fall rate | forward velocity (m/s) "
        "| velocity-tracking error (m/s) | bias (m/s) | ripple (m/s) "
        "| contact-pattern score | mean length |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for r in rows:
        lines.append(
            f"| {r.name} | {r.episodes} | {r.mean_return:,.0f} | {r.fall_rate:.1%} | "
            f"{r.forward_velocity:.4f} | {r.velocity_error:.4f} | {r.velocity_bias:+.4f} | "
            f"{r.velocity_ripple:.4f} | {r.contact_score:.3f} | {r.mean_length:.0f} |"
        )
    return "\n".join(lines)
