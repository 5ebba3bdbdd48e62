"""Evaluation: trained policies and the base gait over fixed-seed, paired episodes.

``evaluate(name, env, seed, policy)`` runs one episode in every env of a batch
(env i starts like a single env seeded seed + i, whatever ran before) and sums
it up as an ``Evaluation``, through the one episode path
(``rwalk.episodes.step``) that training logs with. ``load_policy(checkpoint,
env)`` rebuilds a checkpoint's deterministic policy from the configs its run
stored in config.json (``rwalk.rl.config``), with the observation groups of the
one rule. ``rwalk-play``, ``rwalk-robustness`` and the reports stand on these.
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

from rwalk import episodes
from rwalk.envs.torchrl_env import BatchedEnv
from rwalk.rl.checkpoints import load_checkpoint, trainer_of
from rwalk.rl.config import load_saved_args, observation_groups
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


def saved_run(checkpoint: Path):
    """The flags of ``checkpoint``'s run, read as data from its config.json (``TrainArgs``:
    ``.run``, ``.env``, ``.train`` are its configs).

    Raises:
        FileNotFoundError, ConfigError: naming the file (``rwalk.rl.config.load_saved_args``).
    """
    return load_saved_args(Path(checkpoint).parent / "config.json")


def saved_args(checkpoint: Path) -> dict:
    """The training flags of ``checkpoint``'s run as a dict (``saved_run``)."""
    return dataclasses.asdict(saved_run(checkpoint))


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


def load_policy(checkpoint: Path, env: BatchedEnv) -> Callable[[], torch.Tensor]:
    """The checkpoint's deterministic policy on ``env``: a callable returning the actions
    of the current state. Shape: () -> (N, action_dim)."""
    from rwalk.rl.runner import SafeRunner

    check_checkpoint(checkpoint)
    args = saved_run(checkpoint)
    if args.task != env.core.task.name:
        raise ValueError(
            f"checkpoint {str(checkpoint)!r} is a {args.task!r} policy; the env runs "
            f"{env.core.task.name!r}"
        )
    groups = observation_groups(env.core.task, args.env, args.policy_obs)
    adapter = RslRlVecEnv(env, policy_obs=groups["policy"], critic_obs=groups["critic"],
                          reward_scale=args.reward_scale)  # fmt: skip
    with contextlib.redirect_stdout(io.StringIO()):  # rsl-rl prints the whole architecture
        runner = SafeRunner(adapter, args.train.to_rsl_rl(args.save_interval), log_dir=None,
                            device="cpu")  # fmt: skip
    runner.load(str(checkpoint))
    policy = runner.get_inference_policy()

    def act() -> torch.Tensor:
        with torch.inference_mode():
            return policy(adapter.get_observations())

    return act


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
    core = env.core
    env.set_seed(seed)
    core.reset()
    n = core.num_envs
    limit = core.config.max_episode_steps
    report = progress or (lambda done, total: None)
    report(0, limit)
    first: dict[str, torch.Tensor] = {}  # each env's first episode (the envs run on after it)
    ended = torch.zeros(n, dtype=torch.bool)
    zeros = torch.zeros(n, core.task.action_dim)
    with torch.inference_mode():
        for step in range(limit):
            _, end = episodes.step(core, zeros if policy is None else policy(), auto_reset=False)
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
    length = first["length"]
    errors = first["velocity_error"]
    contact = first.get("sum/contact_pattern", torch.full((n,), math.nan)) / length
    return Evaluation(
        name=name,
        episodes=n,
        mean_return=float(first["return"].mean()),
        fall_rate=float(first["terminated"].double().mean()),
        forward_velocity=float(first["forward_velocity"].mean()),
        velocity_error=float(errors.mean()),
        velocity_error_se=float(errors.std() / n**0.5) if n > 1 else 0.0,
        contact_score=float(contact.mean()),
        mean_length=float(length.mean()),
    )


def table(rows: list[Evaluation]) -> str:
    """The evaluations as a Markdown table."""
    lines = [
        "| run | episodes | mean return | fall rate | forward velocity (m/s) "
        "| velocity-tracking error (m/s) | contact-pattern score | mean length |",
        "| --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for r in rows:
        lines.append(
            f"| {r.name} | {r.episodes} | {r.mean_return:,.0f} | {r.fall_rate:.1%} | "
            f"{r.forward_velocity:.4f} | {r.velocity_error:.4f} | {r.contact_score:.3f} | "
            f"{r.mean_length:.0f} |"
        )
    return "\n".join(lines)
