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

import argparse
import json
import sys
from dataclasses import asdict
from pathlib import Path

from rwalk import presets
from rwalk.cli import (
    NATURAL_INT,
    POSITIVE_FLOAT,
    POSITIVE_INT,
    UNIT_FLOAT,
    command,
    one_line_errors,
)
from rwalk.config import EnvConfig
from rwalk.envs.torchrl_env import BatchedEnv
from rwalk.evaluation import (
    Evaluation,
    acts_in,
    check_policy,
    evaluate,
    load_policy,
    saved_run,
    table,
)
from rwalk.progress import Progress
from rwalk.rl.checkpoints import atomic_write_text


def command_name() -> str:
    """How the user ran this runner, for the usage line."""
    return command("rwalk.runners.play")


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog=command_name(), description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )  # fmt: skip
    add = parser.add_argument
    # fmt: off
    add("--checkpoint", metavar="PATH", type=Path,
        help="rsl-rl checkpoint model_<it>.pt (default: none)")
    add("--base-gait", action="store_true", help="evaluate zero actions (default: off)")
    add("--task", default="residual_walk",
        help="task of a --base-gait run without --checkpoint (default: %(default)s)")
    add("--command", metavar="M/S", type=POSITIVE_FLOAT,
        help="every episode's target velocity, which the reward and the velocity error "
        "track (default: the gait's step_length / cycle_time)")
    add("--episodes", metavar="N", type=POSITIVE_INT, default=100,
        help="episodes, one per env (default: %(default)s)")
    add("--seed", metavar="SEED", type=NATURAL_INT, default=1000,
        help="episode i starts like a single env seeded seed + i (default: %(default)s)")
    add("--terrain-scale", metavar="SCALE", type=UNIT_FLOAT, default=1.0,
        help="terrain roughness, 0 flat .. 1 full (default: %(default)s)")
    add("--max-steps", metavar="STEPS", type=POSITIVE_INT, default=1000,
        help="episode length in env steps (default: %(default)s)")
    add("--settle-steps", metavar="STEPS", type=NATURAL_INT, default=500,
        help="settling at each start (default: %(default)s)")
    add("--video", metavar="PATH", type=Path,
        help="MP4 or GIF of episode 0, needs OpenGL (default: none)")
    add("--video-seconds", metavar="SECONDS", type=POSITIVE_FLOAT, default=10.0,
        help="length of the video (default: %(default)s)")
    add("--viewer", action="store_true",
        help="watch one robot walk in real time in MuJoCo's viewer (needs a display; "
        "Up/Down change a commanded policy's speed) instead of evaluating (default: off)")
    add("--json", metavar="PATH", type=Path, help="save the table's figures here (default: none)")
    add("--progress", action=argparse.BooleanOptionalAction, default=None,
        help="progress lines on stderr (default: only when stderr is a terminal)")
    # fmt: on
    args = parser.parse_args(argv)
    if not args.checkpoint and not args.base_gait:
        parser.error("give --checkpoint PATH, --base-gait, or both")
    if args.viewer and (args.video or args.json):
        parser.error("--viewer watches live: it makes no --video or --json")
    if args.checkpoint:
        try:
            args.task = check_policy(args.checkpoint).task
        except (OSError, ValueError) as error:
            parser.error(f"--checkpoint: {error}")
    try:
        presets.get_task(args.task)
    except ValueError as error:
        parser.error(f"--task: {error}")
    return args


def commanded(args: argparse.Namespace) -> tuple[float, float] | None:
    """The eval env's command range: --command, or the gait's speed for a policy
    trained with commands (it reads one)."""
    trained = args.checkpoint and saved_run(args.checkpoint).command_range
    if args.command is None and not trained:
        return None
    speed = args.command if args.command is not None else EnvConfig().expected_velocity
    return (speed, speed)


def evaluation_env(args: argparse.Namespace, num_envs: int) -> BatchedEnv:
    """``num_envs`` envs of the evaluation world the command line asks for, reading the
    action as the checkpoint's run did."""
    acts = acts_in(args.checkpoint) if args.checkpoint else {"task": args.task}
    config = presets.evaluation_config(
        **acts, terrain_scale=args.terrain_scale, max_steps=args.max_steps,
        settle_steps=args.settle_steps, command_range=commanded(args),
    )  # fmt: skip
    return BatchedEnv(num_envs, config, seed=args.seed, task=args.task)


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


def view(args: argparse.Namespace, launch=None, seconds: float = float("inf")) -> int:
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
    trained = args.checkpoint and saved_run(args.checkpoint).command_range
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


if __name__ == "__main__":
    main()
