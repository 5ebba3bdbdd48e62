"""Evaluate a trained policy, or the base gait, over fixed-seed episodes; optionally film one.

    python -m runners.play --base-gait
    python -m runners.play --checkpoint logs/rwalk/model_149.pt --video docs/policy.mp4
    python -m runners.play --checkpoint logs/rwalk/model_149.pt --base-gait   # both, paired

Every run uses the same starts (seed --seed, env i gets start key seed + i), so
the base gait and a policy meet exactly the same episodes. Episodes are the
spec's (settle 500 steps, up to 1000 steps) on world_train at full roughness,
with starts spread over the terrain. Videos need an OpenGL backend; MUJOCO_GL
defaults to osmesa here (apt-get install libosmesa6).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from dataclasses import asdict, dataclass
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "osmesa")  # must precede the first mujoco import

import numpy as np
import torch

from rwalk import EnvConfig, ResidualWalkVecEnv
from rwalk.constants import OBS_LINVEL
from rwalk.wrappers import RslRlVecEnv


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
    contact_score: float
    """Mean over episodes of the per-step contact_pattern term (max 0.2)."""
    mean_length: float


def eval_config(
    terrain_scale: float = 1.0, max_steps: int = 1000, settle_steps: int = 500
) -> EnvConfig:
    """The spec's episodes on the rough world, starts spread over the terrain."""
    return EnvConfig(
        randomize=True,
        position_noise=(0.5, 1.2),
        terrain_scale=terrain_scale,
        max_episode_steps=max_steps,
        settle_steps=settle_steps,
    )


def load_policy(checkpoint: Path, env: ResidualWalkVecEnv):
    """The checkpoint's deterministic policy and the observation groups it reads."""
    from rwalk.runners.checkpoints import SafeRunner
    from rwalk.runners.train import Args, rsl_rl_config

    saved = json.loads((checkpoint.parent / "config.json").read_text())["args"]
    args = Args(**{k: tuple(v) if isinstance(v, list) else v for k, v in saved.items()})
    adapter = RslRlVecEnv(env, policy_obs=args.policy_obs, reward_scale=args.reward_scale)
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
) -> Evaluation:
    """Run one episode in every env of ``env`` (reset first) and summarise.

    Args:
        seed: env i starts from key seed + i, whatever ran before.
        policy: callable returning (N, 12) actions for the current state; None = base gait.
        record: callable(step) called after every step (e.g. to grab a video frame).
    """
    core = env.core
    env.set_seed(seed)
    core.reset()
    n, vstar = core.num_envs, core.config.expected_velocity
    alive = torch.ones(n, dtype=torch.bool)
    fell = torch.zeros(n, dtype=torch.bool)
    steps = torch.zeros(n)
    totals = {key: torch.zeros(n, dtype=torch.float64) for key in ("return", "v", "err", "contact")}
    zeros = torch.zeros(n, 12)
    with torch.inference_mode():
        for step in range(core.config.max_episode_steps):
            result = core.step(zeros if policy is None else policy())
            a = alive.double()
            v = result.obs[:, OBS_LINVEL.start]
            totals["return"] += a * result.reward
            totals["v"] += a * v
            totals["err"] += a * (v - vstar).abs()
            totals["contact"] += a * result.terms["contact_pattern"]
            steps += alive
            fell |= alive & result.terminated
            alive &= ~(result.terminated | result.truncated)
            if record is not None:
                record(step)
            if not alive.any():
                break
    per_step = {key: (value / steps.double()) for key, value in totals.items() if key != "return"}
    return Evaluation(
        name=name,
        episodes=n,
        mean_return=float(totals["return"].mean()),
        fall_rate=float(fell.double().mean()),
        forward_velocity=float(per_step["v"].mean()),
        velocity_error=float(per_step["err"].mean()),
        contact_score=float(per_step["contact"].mean()),
        mean_length=float(steps.mean()),
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


def main(argv: list[str] | None = None) -> list[Evaluation]:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--checkpoint", type=Path, help="rsl-rl checkpoint (model_<it>.pt)")
    parser.add_argument("--base-gait", action="store_true", help="evaluate zero residuals")
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--seed", type=int, default=1000, help="start keys seed .. seed+episodes")
    parser.add_argument("--terrain-scale", type=float, default=1.0)
    parser.add_argument("--max-steps", type=int, default=1000, help="episode length")
    parser.add_argument("--settle-steps", type=int, default=500, help="settling at each start")
    parser.add_argument("--video", type=Path, help="MP4 or GIF of episode 0 (needs OpenGL)")
    parser.add_argument("--video-seconds", type=float, default=10.0)
    parser.add_argument("--json", type=Path, help="save the table's figures here")
    args = parser.parse_args(argv)
    if not args.checkpoint and not args.base_gait:
        parser.error("give --checkpoint PATH, --base-gait, or both")

    config = eval_config(args.terrain_scale, args.max_steps, args.settle_steps)
    env = ResidualWalkVecEnv(args.episodes, config, seed=args.seed)
    recorder = None
    if args.video:
        from rwalk.render import gl_available

        ok, why = gl_available()
        if ok:
            recorder = VideoRecorder(env, args.video, args.video_seconds)
        else:
            print(
                f"no video: no OpenGL backend for MUJOCO_GL={os.environ['MUJOCO_GL']!r} ({why}); "
                "install one (e.g. apt-get install libosmesa6) or set MUJOCO_GL=egl",
                file=sys.stderr,
            )
    rows = []
    if args.base_gait:
        video = recorder if not args.checkpoint else None
        rows.append(evaluate("base gait", env, args.seed, record=video))
    if args.checkpoint:
        policy = load_policy(args.checkpoint, env)
        rows.append(evaluate(f"policy {args.checkpoint.name}", env, args.seed, policy, recorder))
    print(table(rows))
    if recorder is not None:
        recorder.save()
    if args.json:
        args.json.write_text(json.dumps([asdict(r) for r in rows], indent=2))
    return rows


if __name__ == "__main__":
    main()
