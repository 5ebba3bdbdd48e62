"""PPO built from TorchRL's own parts on ResidualWalkVecEnv: the TorchRL path.

    python -m runners.train_torchrl
    python -m runners.train_torchrl --num-envs 512 --iterations 200 --log-dir logs/torchrl

A Collector steps the batched env (partial resets via "_reset"); GAE computes
advantages; ClipPPOLoss trains a TanhNormal actor and a value network on
minibatches from a replay buffer. The env's keys observation, phase and
lateral_offset are concatenated and normalised (ObservationNorm) and the reward
is scaled (RewardScaling), as train.py does for rsl-rl. Writes checkpoints
(torchrl_<it>.pt) and prints one progress line per iteration.
"""

from __future__ import annotations

import dataclasses
import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import torch
from tensordict.nn import NormalParamExtractor, TensorDictModule
from torch import nn
from torchrl.collectors import Collector
from torchrl.data import LazyTensorStorage, ReplayBuffer
from torchrl.data.replay_buffers.samplers import SamplerWithoutReplacement
from torchrl.envs import CatTensors, Compose, ObservationNorm, RewardScaling, TransformedEnv
from torchrl.modules import MLP, ProbabilisticActor, TanhNormal, ValueOperator
from torchrl.objectives import ClipPPOLoss
from torchrl.objectives.value import GAE

from rwalk import ResidualWalkVecEnv
from rwalk.runners.cli import parse_dataclass
from rwalk.runners.train import Args as RslArgs
from rwalk.runners.train import env_config


@dataclass(frozen=True)
class Args:
    """TorchRL PPO run. Every field is a command-line flag."""

    num_envs: int = field(default=256, metadata={"help": "parallel envs"})
    iterations: int = field(default=50, metadata={"help": "collect + update rounds"})
    steps_per_env: int = field(default=32, metadata={"help": "env steps per env per round"})
    epochs: int = field(default=4, metadata={"help": "passes over each batch"})
    minibatch_size: int = field(default=2048, metadata={"help": "transitions per gradient step"})
    learning_rate: float = field(default=3e-4, metadata={"help": "Adam step"})
    gamma: float = field(default=0.99, metadata={"help": "discount"})
    lmbda: float = field(default=0.95, metadata={"help": "GAE lambda"})
    clip_epsilon: float = field(default=0.2, metadata={"help": "PPO ratio clip"})
    entropy_coef: float = field(default=1e-4, metadata={"help": "entropy bonus"})
    init_noise_std: float = field(default=0.1, metadata={"help": "initial pre-tanh action std"})
    reward_scale: float = field(default=1e-3, metadata={"help": "reward multiplier for PPO"})
    hidden: int = field(default=128, metadata={"help": "width of the two hidden layers"})
    settle_steps: int = field(default=100, metadata={"help": "zero-residual steps at each start"})
    seed: int = field(default=0, metadata={"help": "seed of the envs and of torch"})
    threads: int = field(default=0, metadata={"help": "physics threads (0 = all cores)"})
    log_dir: str = field(default="logs/torchrl", metadata={"help": "output folder"})
    save_interval: int = field(default=25, metadata={"help": "rounds between checkpoints"})


OBS_KEYS = ("observation", "phase", "lateral_offset")


def make_env(args: Args) -> TransformedEnv:
    config = env_config(
        dataclasses.replace(RslArgs(), threads=args.threads, settle_steps=args.settle_steps)
    )
    env = TransformedEnv(
        ResidualWalkVecEnv(args.num_envs, config, seed=args.seed),
        Compose(
            CatTensors(list(OBS_KEYS), "policy_obs", del_keys=False),
            ObservationNorm(in_keys=["policy_obs"], standard_normal=True),
            RewardScaling(loc=0.0, scale=args.reward_scale),
        ),
    )
    env.transform[1].init_stats(num_iter=20, reduce_dim=(0, 1), cat_dim=1)
    return env


def make_modules(args: Args, env: TransformedEnv) -> tuple[ProbabilisticActor, ValueOperator]:
    obs_dim = env.observation_spec["policy_obs"].shape[-1]
    act_dim = env.action_spec.shape[-1]
    body = MLP(in_features=obs_dim, out_features=2 * act_dim, num_cells=[args.hidden] * 2)
    last = body[-1]
    with torch.no_grad():  # start as the base gait: zero mean residual
        last.weight.zero_()
        last.bias.zero_()
    # softplus biased so that a zero pre-activation gives the initial std
    extractor = NormalParamExtractor(scale_mapping=f"biased_softplus_{args.init_noise_std}")
    actor = ProbabilisticActor(
        TensorDictModule(
            nn.Sequential(body, extractor), in_keys=["policy_obs"], out_keys=["loc", "scale"]
        ),
        in_keys=["loc", "scale"],
        spec=env.action_spec,
        distribution_class=TanhNormal,
        distribution_kwargs={"low": -1.0, "high": 1.0},
        return_log_prob=True,
    )
    critic = ValueOperator(
        MLP(in_features=obs_dim, out_features=1, num_cells=[args.hidden] * 2),
        in_keys=["policy_obs"],
    )
    return actor, critic


def train(args: Args) -> Path:
    torch.manual_seed(args.seed)
    log_dir = Path(args.log_dir)
    log_dir.mkdir(parents=True, exist_ok=True)
    (log_dir / "config.json").write_text(json.dumps(dataclasses.asdict(args), indent=2))
    env = make_env(args)
    actor, critic = make_modules(args, env)
    frames = args.num_envs * args.steps_per_env
    collector = Collector(
        env,
        actor,
        frames_per_batch=frames,
        total_frames=frames * args.iterations,
        auto_register_policy_transforms=False,  # the MLP policy keeps no state
    )
    advantage = GAE(gamma=args.gamma, lmbda=args.lmbda, value_network=critic, average_gae=True)
    loss = ClipPPOLoss(
        actor,
        critic,
        clip_epsilon=args.clip_epsilon,
        entropy_coeff=args.entropy_coef,
        critic_coeff=1.0,
        loss_critic_type="smooth_l1",
    )
    optimizer = torch.optim.Adam(loss.parameters(), lr=args.learning_rate)
    buffer = ReplayBuffer(
        storage=LazyTensorStorage(frames),
        sampler=SamplerWithoutReplacement(),
        batch_size=min(args.minibatch_size, frames),
    )
    started = time.perf_counter()
    checkpoint = log_dir / "torchrl_0.pt"
    for it, batch in enumerate(collector):
        with torch.no_grad():
            advantage(batch)
        buffer.extend(batch.reshape(-1))
        for _ in range(args.epochs):
            for _ in range(max(1, frames // buffer.batch_size)):
                parts = loss(buffer.sample())
                total = parts["loss_objective"] + parts["loss_critic"] + parts["loss_entropy"]
                optimizer.zero_grad()
                total.backward()
                nn.utils.clip_grad_norm_(loss.parameters(), 1.0)
                optimizer.step()
        collector.update_policy_weights_()
        ended = batch["next", "done"].squeeze(-1)
        reward = batch["next", "reward"].mean().item() / args.reward_scale
        velocity = batch["next", "observation"][..., 7].mean().item()
        elapsed = time.perf_counter() - started
        eta = elapsed / (it + 1) * (args.iterations - it - 1)
        print(
            f"[torchrl] iteration {it + 1}/{args.iterations}  reward/step {reward:7.2f}  "
            f"v_x {velocity:+.4f} m/s  episodes ended {int(ended.sum())}  "
            f"{frames / (elapsed / (it + 1)):,.0f} frames/s  ETA {eta / 60:.1f} min",
            flush=True,
        )
        if (it + 1) % args.save_interval == 0 or it + 1 == args.iterations:
            checkpoint = log_dir / f"torchrl_{it + 1}.pt"
            torch.save(
                {
                    "iteration": it + 1,
                    "actor": actor.state_dict(),
                    "critic": critic.state_dict(),
                    "optimizer": optimizer.state_dict(),
                    "obs_norm": env.transform[1].state_dict(),
                },
                checkpoint,
            )
    collector.shutdown()
    return checkpoint


def main(argv: list[str] | None = None) -> Path:
    return train(parse_dataclass(Args, argv, __doc__))


if __name__ == "__main__":
    main()
