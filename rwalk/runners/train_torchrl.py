"""PPO built from TorchRL's own parts on ResidualWalkVecEnv: the TorchRL path.

    rwalk-train-torchrl
    rwalk-train-torchrl --num-envs 512 --max-iterations 200 --log-dir logs/torchrl

(In a checkout without installing: python -m runners.train_torchrl ...)

A Collector steps the batched env (partial resets via "_reset"); GAE computes
advantages; ClipPPOLoss trains a TanhNormal actor and a value network on
minibatches from a replay buffer. The env's keys observation, phase and
lateral_offset are concatenated and normalised (ObservationNorm) and the reward
is scaled (RewardScaling), as train.py does for rsl-rl; flags that mean the same
as train.py's have its names. Writes config.json and checkpoints torchrl_<n>.pt
(the state after <n> iterations, every --save-interval and at the end; marked
"trainer": "torchrl"), atomically, and prints one progress line per iteration
(with that iteration's frames/s, overall and while collecting).

Several collector workers (rwalk.runners.torchrl_collect):

    rwalk-train-torchrl --collectors 2                        # 2 local processes
    rwalk-train-torchrl --collectors 2 --backend distributed  # torch.distributed, gloo
    rwalk-train-torchrl --collectors 2 --backend ray          # pip install -e ".[ray]"

--num-envs is per worker: a batch holds collectors x num_envs x num_steps_per_env
frames. Each worker has its own env seeds and --threads physics threads (default
cores // collectors); policy weights go to the workers after every update.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import torch
from tensordict.nn import NormalParamExtractor, TensorDictModule
from torch import nn
from torchrl.collectors import BaseCollector
from torchrl.data import LazyTensorStorage, ReplayBuffer
from torchrl.data.replay_buffers.samplers import SamplerWithoutReplacement
from torchrl.envs import TransformedEnv
from torchrl.modules import MLP, ProbabilisticActor, TanhNormal, ValueOperator
from torchrl.objectives import ClipPPOLoss
from torchrl.objectives.value import GAE

from rwalk.cli import (
    command,
    parse_dataclass,
    require_at_least,
    require_in,
    require_positive,
)
from rwalk.rl.checkpoints import (
    RunSetupError,
    atomic_write_text,
    run_lock,
    save_checkpoint,
)
from rwalk.runners.torchrl_collect import (
    BACKENDS,
    WorkerDied,
    check_workers,
    make_collector,
    make_env,
    require_backend,
)

__all__ = ["Args", "main", "make_env", "make_modules", "train"]


@dataclass(frozen=True)
class Args:
    """TorchRL PPO run. Every field is a command-line flag, checked on creation.

    Raises:
        ValueError: naming the flag, for a value out of its range.
    """

    task: str = field(
        default="residual_walk", metadata={"help": "task: residual_walk or adaptive_gait"}
    )
    num_envs: int = field(
        default=256, metadata={"help": "parallel envs (of each worker with --collectors > 1)"}
    )
    max_iterations: int = field(
        default=50, metadata={"help": "PPO iterations (collect + update rounds)"}
    )
    num_steps_per_env: int = field(default=32, metadata={"help": "rollout length per iteration"})
    num_learning_epochs: int = field(default=4, metadata={"help": "PPO epochs per iteration"})
    num_mini_batches: int = field(default=4, metadata={"help": "minibatches per epoch"})
    learning_rate: float = field(default=3e-4, metadata={"help": "Adam step"})
    gamma: float = field(default=0.99, metadata={"help": "discount"})
    lmbda: float = field(default=0.95, metadata={"help": "GAE lambda"})
    clip_epsilon: float = field(default=0.2, metadata={"help": "PPO ratio clip"})
    entropy_coef: float = field(default=1e-4, metadata={"help": "entropy bonus"})
    init_noise_std: float = field(default=0.1, metadata={"help": "initial pre-tanh action std"})
    reward_scale: float = field(default=1e-3, metadata={"help": "reward multiplier for PPO"})
    hidden_dims: tuple[int, ...] = field(default=(128, 128), metadata={"help": "MLP layers"})
    settle_steps: int = field(default=100, metadata={"help": "zero-residual steps at each start"})
    seed: int = field(
        default=0,
        metadata={"help": "seed of the envs (worker w's from seed + w * num_envs) and of torch"},
    )
    threads: int = field(
        default=0,
        metadata={
            "help": "physics threads (0 = all cores); with several collectors, the physics "
            "and torch threads of each worker (0 = cores // --collectors)"
        },
    )
    collectors: int = field(
        default=1,
        metadata={
            "help": "collector workers, each stepping its own --num-envs envs "
            "(1 with the process backend: the envs step in this process)"
        },
    )
    backend: str = field(
        default="process",
        metadata={
            "help": "where collector workers run: process (local processes), distributed "
            '(torch.distributed with gloo, local processes) or ray (pip install -e ".[ray]")'
        },
    )
    log_dir: str = field(default="logs/torchrl", metadata={"help": "output folder"})
    save_interval: int = field(
        default=25, metadata={"help": "save torchrl_<n>.pt every this many iterations"}
    )

    def __post_init__(self) -> None:
        from rwalk.tasks import get_task

        get_task(self.task)  # ValueError listing the known tasks
        require_at_least(
            self,
            1,
            "num_envs",
            "max_iterations",
            "num_steps_per_env",
            "num_learning_epochs",
            "num_mini_batches",
            "save_interval",
            "collectors",
        )
        if self.backend not in BACKENDS:
            known = ", ".join(BACKENDS)
            raise ValueError(f"--backend must be one of {known}, got {self.backend!r}")
        require_at_least(self, 0, "settle_steps", "threads", "seed", "entropy_coef")
        require_positive(self, "learning_rate", "init_noise_std", "reward_scale", "clip_epsilon")
        require_in(self, "gamma", 0.0, 1.0, low_open=True)
        require_in(self, "lmbda", 0.0, 1.0)
        if not self.hidden_dims or min(self.hidden_dims) < 1:
            raise ValueError(f"--hidden-dims must be sizes >= 1, got {self.hidden_dims}")
        frames = self.collectors * self.num_envs * self.num_steps_per_env
        if self.num_mini_batches > frames:
            product = "--num-envs * --num-steps-per-env"
            if self.collectors > 1:
                product = "--collectors * " + product
            raise ValueError(
                f"--num-mini-batches must be <= {product} = {frames}, got {self.num_mini_batches}"
            )


def make_modules(args: Args, env: TransformedEnv) -> tuple[ProbabilisticActor, ValueOperator]:
    obs_dim = env.observation_spec["policy_obs"].shape[-1]
    act_dim = env.action_spec.shape[-1]
    body = MLP(in_features=obs_dim, out_features=2 * act_dim, num_cells=list(args.hidden_dims))
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
        MLP(in_features=obs_dim, out_features=1, num_cells=list(args.hidden_dims)),
        in_keys=["policy_obs"],
    )
    return actor, critic


def train(args: Args) -> Path:
    """Run the training; returns the last checkpoint's path."""
    require_backend(args.backend)  # before anything is written
    with run_lock(args.log_dir):  # one run writes to a folder at a time
        return _train(args, Path(args.log_dir))


def _train(args: Args, log_dir: Path) -> Path:
    torch.manual_seed(args.seed)
    atomic_write_text(log_dir / "config.json", json.dumps(dataclasses.asdict(args), indent=2))
    env = make_env(args)  # with several collectors: for the specs and the normalisation
    actor, critic = make_modules(args, env)
    obs_norm = env.transform[1].state_dict()
    collector = make_collector(args, env, actor)
    del env  # with several collectors the workers step their own envs
    try:
        checkpoint = _learn(args, log_dir, collector, actor, critic, obs_norm)
    except BaseException:
        # Shut the workers down on an error too (they would keep this process alive), but
        # report the error itself: with a worker lost, shutting down may fail as well.
        with contextlib.suppress(Exception):
            collector.shutdown()
        raise
    collector.shutdown()
    return checkpoint


def _learn(
    args: Args,
    log_dir: Path,
    collector: BaseCollector,
    actor: ProbabilisticActor,
    critic: ValueOperator,
    obs_norm: dict,
) -> Path:
    """PPO on the collector's batches; returns the last checkpoint's path."""
    frames = args.collectors * args.num_envs * args.num_steps_per_env
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
        batch_size=frames // args.num_mini_batches,
    )
    started = tick = time.perf_counter()
    checkpoint = log_dir / "torchrl_0.pt"
    for it, batch in enumerate(collector):  # (num_envs, T) or (collectors, num_envs, T)
        collected = time.perf_counter()
        with torch.no_grad():
            advantage(batch)
        buffer.extend(batch.reshape(-1))
        for _ in range(args.num_learning_epochs):
            for _ in range(args.num_mini_batches):
                parts = loss(buffer.sample())
                total = parts["loss_objective"] + parts["loss_critic"] + parts["loss_entropy"]
                optimizer.zero_grad()
                total.backward()
                nn.utils.clip_grad_norm_(loss.parameters(), 1.0)
                optimizer.step()
        check_workers(collector)  # a dead one would never acknowledge the weights
        collector.update_policy_weights_()  # to the workers, when there are any
        ended = batch["next", "done"].squeeze(-1)
        reward = batch["next", "reward"].mean().item() / args.reward_scale
        velocity = batch["next", "observation"][..., 7].mean().item()
        now = time.perf_counter()
        eta = (now - started) / (it + 1) * (args.max_iterations - it - 1)
        print(
            f"[torchrl] iteration {it + 1}/{args.max_iterations}  reward/step {reward:7.2f}  "
            f"v_x {velocity:+.4f} m/s  episodes ended {int(ended.sum())}  "
            f"{frames / (now - tick):,.0f} frames/s "
            f"(collecting {frames / (collected - tick):,.0f})  ETA {eta / 60:.1f} min",
            flush=True,
        )
        if (it + 1) % args.save_interval == 0 or it + 1 == args.max_iterations:
            checkpoint = log_dir / f"torchrl_{it + 1}.pt"
            save_checkpoint(
                {
                    "trainer": "torchrl",
                    "iteration": it + 1,
                    "actor": actor.state_dict(),
                    "critic": critic.state_dict(),
                    "optimizer": optimizer.state_dict(),
                    "obs_norm": obs_norm,
                },
                checkpoint,
            )
        tick = time.perf_counter()  # saving is no part of an iteration's frames/s
    return checkpoint


def main(argv: list[str] | None = None) -> None:
    """The ``rwalk-train-torchrl`` command."""
    prog = command("rwalk.runners.train_torchrl")
    args = parse_dataclass(Args, argv, __doc__, prog=prog)
    try:
        train(args)
    except (RunSetupError, WorkerDied) as error:  # folder in use, extra missing, worker lost
        raise SystemExit(f"{prog}: error: {error}") from None


if __name__ == "__main__":
    main()
