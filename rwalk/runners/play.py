"""Evaluate a trained policy, or the base gait, over fixed-seed episodes; optionally film one.

    rwalk-play --base-gait
    rwalk-play --checkpoint logs/rwalk/model_149.pt --video docs/policy.mp4
    rwalk-play --checkpoint logs/rwalk/model_149.pt --base-gait   # both, paired
    rwalk-play --checkpoint logs/adaptive/model_299.pt --command 0.2   # ask for 0.2 m/s
    rwalk-play --checkpoint logs/rwalk/model_299.pt --viewer   # watch it walk, live

(``python -m rwalk.runners.play`` in a checkout.) Checkpoints are rsl-rl's, from
rwalk-train (model_<it>.pt, with the config.json it writes beside them); the
checkpoint's task (config.json) sets the task, --task the base gait's without one.
--command V makes V m/s every episode's target velocity: the reward and the
velocity error track it, and a policy trained with commands (--command-range)
reads it (default for such a policy: the gait's step_length / cycle_time).

Every run uses the same starts (seed --seed: episode i starts like a single env
seeded --seed + i), so the base gait and a policy meet exactly the same episodes.
Episodes are the spec's (settle 500 steps, up to 1000 steps) on world_train at
full roughness, with starts spread over the terrain. Only --video needs OpenGL:
with MUJOCO_GL unset and no display it takes EGL or OSMesa, whichever loads
(apt-get install libosmesa6), and without one it evaluates without a video.

--viewer shows one robot walking in real time in MuJoCo's viewer instead of
evaluating (a new episode starts when one ends; close the window to stop). For a
policy trained with commands, Up and Down change the speed within its command
range. It needs a display: without one it stops at once, in one line saying so.
"""

from __future__ import annotations

import dataclasses
import json
import sys
from dataclasses import asdict, dataclass
from pathlib import Path

from rwalk import evaluation, presets
from rwalk.cli import command, one_line_errors, parse, usage_error
from rwalk.config import EnvConfig
from rwalk.envs.torchrl_env import BatchedEnv
from rwalk.evaluation import (
    Evaluation,
    check_policy,
    evaluate,
    load_policy,
    table,
    trained_env,
)
from rwalk.progress import Progress
from rwalk.rl.checkpoints import atomic_write_text, check_outputs
from rwalk.validation import require_at_least, require_at_most, require_in, require_positive

#: Largest count a command line takes (int32: episodes, steps).
MAX_COUNT = 2**31 - 1


@dataclass(frozen=True)
class PlayArgs:
    """rwalk-play's command line (each field a flag)."""

    checkpoint: Path | None = None
    """rsl-rl checkpoint model_<it>.pt"""
    base_gait: bool = False
    """evaluate zero actions"""
    task: str = "residual_walk"
    """task of a --base-gait run without --checkpoint"""
    command: float | None = None
    """every episode's target velocity in m/s, which the reward and the velocity error track
    (None: the gait's step_length / cycle_time)"""
    episodes: int = 100
    """episodes, one per env"""
    seed: int = 1000
    """episode i starts like a single env seeded seed + i"""
    terrain_scale: float = 1.0
    """terrain roughness, 0 flat .. 1 full"""
    max_steps: int = presets.EVALUATION.max_episode_steps
    """episode length in env steps"""
    settle_steps: int = presets.EVALUATION.settle_steps
    """settling at each start"""
    video: Path | None = None
    """MP4 or GIF of episode 0, needs OpenGL"""
    video_seconds: float = 10.0
    """length of the video"""
    viewer: bool = False
    """watch one robot walk in real time in MuJoCo's viewer (needs a display; Up/Down change a
    commanded policy's speed) instead of evaluating"""
    json: Path | None = None
    """save the table's figures here"""
    progress: bool = False
    """progress lines on stderr (when not given: only if stderr is a terminal)"""

    def __post_init__(self) -> None:
        require_at_least(self, 1, "episodes", "max_steps")
        require_at_least(self, 0, "settle_steps", "seed")
        require_at_most(self, MAX_COUNT, "episodes", "max_steps", "settle_steps", "seed")
        require_in(self, "terrain_scale", 0.0, 1.0)
        require_positive(self, "video_seconds")
        if self.command is not None:
            require_positive(self, "command")


def command_name() -> str:
    """How the user ran this runner, for the usage line."""
    return command("rwalk.runners.play")


def parse_args(argv: list[str] | None = None) -> PlayArgs:
    """``argv`` as rwalk-play's arguments; the checkpoint's task (from its record) replaces
    --task. Exits 2 with one line naming a bad flag or file."""
    prog = command_name()
    default = PlayArgs(progress=sys.stderr.isatty())
    args = parse(PlayArgs, argv, prog=prog, description=__doc__, default=default)
    if not args.checkpoint and not args.base_gait:
        usage_error(prog, "give --checkpoint PATH, --base-gait, or both")
    if args.viewer and (args.video or args.json):
        usage_error(prog, "--viewer watches live: it makes no --video or --json")
    check_outputs(prog, {"--json": args.json, "--video": args.video})
    task = args.task
    if args.checkpoint:
        try:
            task = check_policy(args.checkpoint).task
        except (OSError, ValueError) as error:
            usage_error(prog, f"--checkpoint: {error}")
    try:
        presets.get_task(task)
    except ValueError as error:
        usage_error(prog, f"--task: {error}")
    return dataclasses.replace(args, task=task)


def commanded(args: PlayArgs) -> tuple[float, float] | None:
    """The eval env's command range: --command, or the gait's speed for a policy
    trained with commands (it reads one)."""
    trained = args.checkpoint and trained_env(args.checkpoint).command_range
    if args.command is None and not trained:
        return None
    speed = args.command if args.command is not None else EnvConfig().expected_velocity
    return (speed, speed)


def evaluation_env(args: PlayArgs, num_envs: int) -> BatchedEnv:
    """``num_envs`` envs of the evaluation world the command line asks for, acting as the
    checkpoint's run trained (its record)."""
    return evaluation.evaluation_env(
        args.checkpoint, num_envs, args.seed, args.task, terrain_scale=args.terrain_scale,
        max_episode_steps=args.max_steps, settle_steps=args.settle_steps,
        command_range=commanded(args),
    )  # fmt: skip


def play(argv: list[str] | None = None) -> list[Evaluation]:
    """Run the command line ``argv``; returns its table's rows."""
    args = parse_args(argv)
    if args.viewer:
        view(args)
        return []
    env = evaluation_env(args, args.episodes)
    env.core.settle_progress = Progress("settling starts", "physics steps", enabled=args.progress)
    recorder = None
    if args.video:
        from rwalk.render import VideoRecorder, gl_available

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
        atomic_write_text(args.json, json.dumps([asdict(r) for r in rows], indent=2))
    return rows


def view(args: PlayArgs, launch=None, seconds: float = float("inf")) -> int:
    """--viewer: one robot, live (``launch``: a stand-in for mujoco.viewer's, in tests);
    returns the steps shown.

    Raises:
        OSError: no display, naming what is missing (before anything is built).
    """
    from rwalk.viewer import SPEED_STEP, display_missing, watch

    missing = display_missing() if launch is None else None
    if missing:
        raise OSError(missing)
    env = evaluation_env(args, 1)
    policy = load_policy(args.checkpoint, env) if args.checkpoint else None
    trained = args.checkpoint and trained_env(args.checkpoint).command_range
    speeds = tuple(trained) if trained else None
    if speeds:
        speed = commanded(args)[0]
        print(f"command {speed:.3f} m/s: Up/Down change it by {SPEED_STEP} within {speeds}")
    return watch(env, policy, speeds, launch=launch, seconds=seconds,
                 realtime=launch is None)  # fmt: skip


@one_line_errors("rwalk.runners.play")
def main(argv: list[str] | None = None) -> None:
    """Console script ``rwalk-play`` (returns None: its exit status is 0)."""
    play(argv)


if __name__ == "__main__":  # through the module by name, where tyro reads PlayArgs's types
    from rwalk.runners.play import main as play_main

    play_main()
