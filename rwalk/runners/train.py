"""Train a residual policy with rsl-rl's PPO on the batched env.

    python -m runners.train                      # short defaults for a 2-core CPU
    python -m runners.train --max-minutes 30 --max-iterations 100000
    python -m runners.train --resume logs/rwalk/model_49.pt --max-iterations 200

Writes to --log-dir: TensorBoard events (every reward term, episode length, fall
rate, forward velocity), checkpoints model_<it>.pt every --save-interval
iterations, config.json (what play.py needs to rebuild the env), and at the end
exported/policy.pt (TorchScript) and exported/policy.onnx.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from rwalk import EnvConfig, ResidualWalkVecEnv
from rwalk.runners.cli import parse_dataclass
from rwalk.wrappers import RslRlVecEnv


@dataclass(frozen=True)
class Args:
    """Training run. Every field is a command-line flag (--num-envs, ...)."""

    num_envs: int = field(default=1024, metadata={"help": "parallel envs"})
    max_iterations: int = field(default=150, metadata={"help": "PPO iterations in total"})
    max_minutes: float = field(
        default=math.inf, metadata={"help": "stop at a checkpoint after this much wall time"}
    )
    log_dir: str = field(default="logs/rwalk", metadata={"help": "output folder"})
    seed: int = field(default=0, metadata={"help": "seed of the envs and of torch"})
    resume: str = field(default="", metadata={"help": "checkpoint to continue from"})
    terrain_scale: float = field(default=1.0, metadata={"help": "final terrain roughness 0..1"})
    curriculum_iterations: int = field(
        default=0,
        metadata={"help": "ramp the roughness from 0 to --terrain-scale over these iterations"},
    )
    save_interval: int = field(default=25, metadata={"help": "iterations between checkpoints"})
    num_steps_per_env: int = field(default=24, metadata={"help": "rollout length per iteration"})
    settle_steps: int = field(default=100, metadata={"help": "zero-residual steps at each start"})
    settle_pool_fraction: float = field(
        default=0.25, metadata={"help": "settled starts kept ready, as a fraction of num_envs"}
    )
    settle_reuse: int = field(default=4, metadata={"help": "resets served by each pooled start"})
    max_episode_steps: int = field(default=1000, metadata={"help": "episode length (50 Hz)"})
    reward_scale: float = field(default=1e-3, metadata={"help": "reward multiplier seen by PPO"})
    hidden_dims: tuple[int, ...] = field(default=(128, 128), metadata={"help": "MLP layers"})
    learning_rate: float = field(default=1e-3, metadata={"help": "Adam step (adaptive on KL)"})
    entropy_coef: float = field(default=0.005, metadata={"help": "entropy bonus"})
    init_noise_std: float = field(default=0.1, metadata={"help": "initial action std"})
    num_learning_epochs: int = field(default=5, metadata={"help": "PPO epochs per iteration"})
    num_mini_batches: int = field(default=4, metadata={"help": "minibatches per epoch"})
    gamma: float = field(default=0.99, metadata={"help": "discount"})
    policy_obs: tuple[str, ...] = field(
        default=("observation", "phase", "lateral_offset"),
        metadata={"help": "observation pieces the policy sees"},
    )
    threads: int = field(default=0, metadata={"help": "physics threads (0 = all cores)"})
    export: bool = field(default=True, metadata={"help": "export TorchScript and ONNX at the end"})


def parse_args(argv: list[str] | None = None) -> Args:
    return parse_dataclass(Args, argv, __doc__)


def env_config(args: Args) -> EnvConfig:
    """The training env: rough world, starts spread over the terrain, pooled settling."""
    start_scale = 0.0 if args.curriculum_iterations > 0 else args.terrain_scale
    return EnvConfig(
        model_path="model/world_train.xml",
        terrain_scale=start_scale,
        randomize=True,
        position_noise=(0.5, 1.2),
        settle_steps=args.settle_steps,
        settle_pool=max(1, round(args.settle_pool_fraction * args.num_envs)),
        settle_reuse=args.settle_reuse,
        max_episode_steps=args.max_episode_steps,
        num_threads=args.threads,
    )


def rsl_rl_config(args: Args) -> dict[str, Any]:
    """rsl-rl-lib 5.x training config (a fresh dict: its PPO pops keys from it)."""
    mlp = {"class_name": "MLPModel", "hidden_dims": list(args.hidden_dims), "activation": "elu"}
    return {
        "num_steps_per_env": args.num_steps_per_env,
        "save_interval": args.save_interval,
        "obs_groups": {"actor": ["policy"], "critic": ["critic"]},
        "algorithm": {
            "class_name": "PPO",
            "learning_rate": args.learning_rate,
            "entropy_coef": args.entropy_coef,
            "num_learning_epochs": args.num_learning_epochs,
            "num_mini_batches": args.num_mini_batches,
            "gamma": args.gamma,
            "lam": 0.95,
            "schedule": "adaptive",
            "desired_kl": 0.01,
            "clip_param": 0.2,
            "value_loss_coef": 1.0,
            "use_clipped_value_loss": False,
            "max_grad_norm": 1.0,
        },
        "actor": {
            **mlp,
            "obs_normalization": True,
            "distribution_cfg": {
                "class_name": "GaussianDistribution",
                "init_std": args.init_noise_std,
            },
        },
        "critic": {**mlp, "obs_normalization": True},
    }


def make_env(args: Args) -> RslRlVecEnv:
    vec = ResidualWalkVecEnv(args.num_envs, env_config(args), seed=args.seed)
    return RslRlVecEnv(
        vec,
        policy_obs=args.policy_obs,
        critic_obs=("observation", "phase", "lateral_offset"),
        reward_scale=args.reward_scale,
    )


def start_as_base_gait(runner) -> None:
    """Zero the actor's output layer: the untrained policy's mean residual is 0, so
    training starts from the base gait (random output weights made the robots
    stumble: white-noise residuals of a few mm at 50 Hz stop the gait)."""
    last = [m for m in runner.alg.get_policy().mlp.modules() if isinstance(m, torch.nn.Linear)][-1]
    with torch.no_grad():
        last.weight.zero_()
        last.bias.zero_()


def terrain_at(args: Args, iteration: int) -> float:
    """Terrain roughness for an iteration (linear ramp over curriculum_iterations)."""
    if args.curriculum_iterations <= 0:
        return args.terrain_scale
    return args.terrain_scale * min(1.0, iteration / args.curriculum_iterations)


def train(args: Args) -> Path:
    """Run the training; returns the last checkpoint's path."""
    from rwalk.runners.checkpoints import SafeRunner

    clock = time.perf_counter()  # the wall-time budget counts from here, env building included
    torch.manual_seed(args.seed)
    log_dir = Path(args.log_dir)
    log_dir.mkdir(parents=True, exist_ok=True)
    print(f"building {args.num_envs} envs (settling their starts) ...", flush=True)
    env = make_env(args)
    print(f"  ready in {time.perf_counter() - clock:.1f} s", flush=True)
    runner = SafeRunner(env, rsl_rl_config(args), log_dir=str(log_dir), device="cpu")
    checkpoint = None
    if not args.resume:
        start_as_base_gait(runner)
    if args.resume:
        runner.load(args.resume)
        runner.current_learning_iteration += 1  # continue after the saved iteration
        checkpoint = Path(args.resume)
        print(f"resumed from {args.resume}: next iteration {runner.current_learning_iteration}")
    (log_dir / "config.json").write_text(
        json.dumps(
            {"args": dataclasses.asdict(args), "env": dataclasses.asdict(env.env.config)},
            indent=2,
        )
    )

    first = runner.current_learning_iteration
    budget = args.max_minutes * 60.0
    while runner.current_learning_iteration < args.max_iterations:
        it = runner.current_learning_iteration
        remaining = args.max_iterations - it
        scale = terrain_at(args, it)
        if scale != env.core.terrain.scale:
            env.env.set_terrain_scale(scale)
        chunk = min(args.save_interval, remaining)
        runner.learn(num_learning_iterations=chunk, init_at_random_ep_len=it == first)
        runner.logger.writer.close()  # learn() opens a new writer each call
        runner.current_learning_iteration += 1  # learn() leaves it at its last iteration
        checkpoint = log_dir / f"model_{runner.current_learning_iteration - 1}.pt"
        done = runner.current_learning_iteration - first
        elapsed = time.perf_counter() - clock
        per_iteration = elapsed / done
        left = args.max_iterations - runner.current_learning_iteration
        eta = min(left * per_iteration, max(budget - elapsed, 0.0))
        print(
            f"[rwalk] iteration {runner.current_learning_iteration}/{args.max_iterations}, "
            f"{elapsed / 60:.1f} min elapsed, terrain {scale:.2f}, ETA {eta / 60:.1f} min, "
            f"checkpoint {checkpoint}",
            flush=True,
        )
        if elapsed + per_iteration * min(args.save_interval, left) > budget:
            print(f"[rwalk] stopping: the {args.max_minutes:g}-minute budget is reached")
            break

    if args.export:
        from rwalk.export import export_policy

        jit_path, onnx_path = export_policy(runner, log_dir / "exported")
        print(f"[rwalk] exported {jit_path} and {onnx_path} (layout: policy.json)")
    if checkpoint is None:
        raise ValueError(f"nothing to train: --max-iterations {args.max_iterations}")
    return checkpoint


def main(argv: list[str] | None = None) -> Path:
    return train(parse_args(argv))


if __name__ == "__main__":
    main()
