"""Evaluate a trained policy, or the base gait, over fixed-seed episodes; optionally film one.

    rwalk-play --base-gait
    rwalk-play --checkpoint logs/rwalk/model_149.pt --video docs/policy.mp4
    rwalk-play --checkpoint logs/rwalk/model_149.pt --base-gait   # both, paired
    rwalk-play --checkpoint logs/adaptive/model_299.pt --command 0.2   # ask for 0.2 m/s

(``python -m rwalk.runners.play`` in a checkout.) Checkpoints are rsl-rl's, from
rwalk-train (model_<it>.pt, with the config.json it writes beside them); the
checkpoint's task (config.json) sets the task, --task the base gait's without one.
--command V makes V m/s every episode's target velocity: the reward and the
velocity error track it, and a policy trained with commands (--command-range)
reads it (default for such a policy: the gait's step_length / cycle_time).

Every run uses the same starts (seed --seed: episode i starts like a single env
seeded --seed + i), so the base gait and a policy meet exactly the same episodes. Episodes are the
spec's (settle 500 steps, up to 1000 steps) on world_train at full roughness,
with starts spread over the terrain. Only --video needs OpenGL: with MUJOCO_GL
unset and no display it takes EGL or OSMesa, whichever loads
(apt-get install libosmesa6), and without one it evaluates without a video.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import sys
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch

from rwalk import EnvConfig, ResidualWalkVecEnv, episodes, presets
from rwalk.progress import Progress
from rwalk.runners.cli import NATURAL_INT, POSITIVE_FLOAT, POSITIVE_INT, UNIT_FLOAT
from rwalk.tasks.base import PRIVILEGED_PIECES
from rwalk.wrappers import RslRlVecEnv

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


def eval_config(
    terrain_scale: float = 1.0, max_steps: int = 1000, settle_steps: int = 500
) -> EnvConfig:
    """The spec's episodes on the rough world, starts spread over the terrain."""
    return presets.evaluation_config("residual_walk", terrain_scale, max_steps, settle_steps)


def saved_args(checkpoint: Path) -> dict:
    """The training flags of ``checkpoint``'s run (its config.json)."""
    return json.loads((checkpoint.parent / "config.json").read_text())["args"]


def checkpoint_trainer(saved: dict) -> str:
    """The trainer that wrote a loaded checkpoint: its ``"trainer"`` key, else
    ``"torchrl"`` / ``"rsl_rl"`` from its keys, else ``"unknown"``."""
    if "trainer" in saved:
        return str(saved["trainer"])
    if {"iteration", "actor"} <= saved.keys():
        return "torchrl"
    if {"iter", "actor_state_dict"} <= saved.keys():
        return "rsl_rl"
    return "unknown"


def check_checkpoint(checkpoint: Path) -> None:
    """Fail before any work, naming the file, if play cannot evaluate ``checkpoint``.

    Raises:
        FileNotFoundError: the checkpoint, or the config.json beside it, is missing.
        ValueError: the file is not a readable checkpoint, or another trainer wrote it.
    """
    from rwalk.runners.checkpoints import load_checkpoint

    trainer = checkpoint_trainer(load_checkpoint(checkpoint))
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


def load_policy(checkpoint: Path, env: ResidualWalkVecEnv):
    """The checkpoint's deterministic policy and the observation groups it reads."""
    from rwalk.runners.checkpoints import SafeRunner
    from rwalk.runners.train import Args, policy_pieces, rsl_rl_config

    check_checkpoint(checkpoint)
    saved = saved_args(checkpoint)
    args = Args.from_saved(saved)
    if args.task != env.core.task.name:
        raise ValueError(
            f"checkpoint {str(checkpoint)!r} is a {args.task!r} policy; the env runs "
            f"{env.core.task.name!r}"
        )
    pieces = policy_pieces(args, env.core.task)
    # A robust run's critic also read the privileged pieces (the policy never does).
    critic = (*pieces, *PRIVILEGED_PIECES) if args.robust else pieces
    adapter = RslRlVecEnv(env, policy_obs=pieces, critic_obs=critic, reward_scale=args.reward_scale)
    with contextlib.redirect_stdout(io.StringIO()):  # rsl-rl prints the whole architecture
        runner = SafeRunner(adapter, rsl_rl_config(args), log_dir=None, device="cpu")
    runner.load(str(checkpoint))
    policy = runner.get_inference_policy()

    def act() -> torch.Tensor:
        with torch.inference_mode():
            return policy(adapter.get_observations())

    return act


def evaluate(
    name: str,
    env: ResidualWalkVecEnv,
    seed: int,
    policy=None,
    record=None,
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


class VideoRecorder:
    """Frames of env 0 for the first ``seconds`` of an evaluation, written as MP4 or GIF."""

    def __init__(self, env: ResidualWalkVecEnv, path: Path, seconds: float) -> None:
        from rwalk.render import FrameRenderer

        self.path, self.env = path, env
        self.renderer = FrameRenderer(env.core.model)
        self.frames: list[np.ndarray] = []
        self.limit = round(seconds / env.core.control_dt)

    def __call__(self, step: int) -> None:
        if step < self.limit:
            self.frames.append(self.renderer.frame(self.env.core.sim, 0))

    def save(self) -> None:
        import imageio.v3 as iio

        fps = round(1.0 / self.env.core.control_dt)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        if self.path.suffix == ".gif":
            iio.imwrite(self.path, self.frames[::2], duration=2000 // fps, loop=0)
        else:
            iio.imwrite(self.path, self.frames, fps=fps, codec="libx264")
        self.renderer.close()
        print(f"wrote {self.path} ({len(self.frames)} frames)")


def command_name(module: str = "rwalk.runners.play") -> str:
    """How the user ran this runner, for the usage line: the console script's name
    (``rwalk-play``), else ``python -m <module>``."""
    script = Path(sys.argv[0]).name if sys.argv and sys.argv[0] else ""
    if script.startswith("rwalk-"):
        return script
    spec = getattr(sys.modules.get("__main__"), "__spec__", None)
    if spec is not None and spec.name.rsplit(".", 1)[-1] == module.rsplit(".", 1)[-1]:
        return f"python -m {spec.name}"  # the checkout shim: python -m runners.play
    return f"python -m {module}"


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog=command_name(),
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add = parser.add_argument
    add(
        "--checkpoint",
        metavar="PATH",
        type=Path,
        help="rsl-rl checkpoint model_<it>.pt (default: none)",
    )
    add("--base-gait", action="store_true", help="evaluate zero actions (default: off)")
    add(
        "--task",
        default="residual_walk",
        help="task of a --base-gait run without --checkpoint (default: %(default)s)",
    )
    add(
        "--command",
        metavar="M/S",
        type=POSITIVE_FLOAT,
        help="every episode's target velocity, which the reward and the velocity error "
        "track (default: the gait's step_length / cycle_time)",
    )
    add(
        "--episodes",
        metavar="N",
        type=POSITIVE_INT,
        default=100,
        help="episodes, one per env (default: %(default)s)",
    )
    add(
        "--seed",
        metavar="SEED",
        type=NATURAL_INT,
        default=1000,
        help="episode i starts like a single env seeded seed + i (default: %(default)s)",
    )
    add(
        "--terrain-scale",
        metavar="SCALE",
        type=UNIT_FLOAT,
        default=1.0,
        help="terrain roughness, 0 flat .. 1 full (default: %(default)s)",
    )
    add(
        "--max-steps",
        metavar="STEPS",
        type=POSITIVE_INT,
        default=1000,
        help="episode length in env steps (default: %(default)s)",
    )
    add(
        "--settle-steps",
        metavar="STEPS",
        type=NATURAL_INT,
        default=500,
        help="settling at each start (default: %(default)s)",
    )
    add(
        "--video",
        metavar="PATH",
        type=Path,
        help="MP4 or GIF of episode 0, needs OpenGL (default: none)",
    )
    add(
        "--video-seconds",
        metavar="SECONDS",
        type=POSITIVE_FLOAT,
        default=10.0,
        help="length of the video (default: %(default)s)",
    )
    add("--json", metavar="PATH", type=Path, help="save the table's figures here (default: none)")
    add(
        "--progress",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="progress lines on stderr (default: only when stderr is a terminal)",
    )
    args = parser.parse_args(argv)
    if not args.checkpoint and not args.base_gait:
        parser.error("give --checkpoint PATH, --base-gait, or both")
    if args.checkpoint:
        try:
            check_checkpoint(args.checkpoint)
        except (FileNotFoundError, ValueError) as error:
            parser.error(f"--checkpoint: {error}")
        args.task = saved_args(args.checkpoint).get("task", "residual_walk")
    try:
        presets.get_task(args.task)
    except ValueError as error:
        parser.error(f"--task: {error}")
    return args


def commanded(args: argparse.Namespace) -> tuple[float, float] | None:
    """The eval env's command range: --command, or the gait's speed for a policy
    trained with commands (it reads one)."""
    trained = args.checkpoint and saved_args(args.checkpoint).get("command_range")
    if args.command is None and not trained:
        return None
    speed = args.command if args.command is not None else EnvConfig().expected_velocity
    return (speed, speed)


def play(argv: list[str] | None = None) -> list[Evaluation]:
    """Run the command line ``argv``; returns its table's rows."""
    args = parse_args(argv)
    config = presets.evaluation_config(
        args.task, args.terrain_scale, args.max_steps, args.settle_steps, commanded(args)
    )
    env = ResidualWalkVecEnv(args.episodes, config, seed=args.seed, task=args.task)
    env.core.settle_progress = Progress("settling starts", "physics steps", enabled=args.progress)
    recorder = None
    if args.video:
        from rwalk.render import gl_available

        ok, why = gl_available()
        if ok:
            recorder = VideoRecorder(env, args.video, args.video_seconds)
        else:
            print(f"no video: {why}", file=sys.stderr)
    rows = []

    def run(name: str, policy=None, record=None) -> None:
        progress = Progress(f"evaluating {name}", enabled=args.progress)
        rows.append(evaluate(name, env, args.seed, policy, record, progress))

    if args.base_gait:
        run("base gait", record=recorder if not args.checkpoint else None)
    if args.checkpoint:
        run(f"policy {args.checkpoint.name}", load_policy(args.checkpoint, env), recorder)
    print(table(rows))
    if recorder is not None:
        recorder.save()
    if args.json:
        from rwalk.runners.checkpoints import atomic_write_text

        atomic_write_text(args.json, json.dumps([asdict(r) for r in rows], indent=2))
    return rows


def main(argv: list[str] | None = None) -> None:
    """Console script ``rwalk-play`` (returns None: its exit status is 0)."""
    play(argv)


if __name__ == "__main__":
    main()
