"""Train a policy for a task with rsl-rl's PPO on the batched env.

    rwalk-train                                  # short defaults for a 2-core CPU
    rwalk-train --task adaptive_gait --command-range 0.05 0.25
    rwalk-train --max-minutes 30 --max-iterations 100000
    rwalk-train --resume logs/rwalk --max-iterations 200     # newest checkpoint there
    rwalk-train --resume logs/rwalk/model_49.pt --max-iterations 200

(In a checkout without installing: python -m runners.train ...)

One training over several processes, on one machine or several (rsl-rl's
data-parallel PPO on gloo; see rwalk.runners.distributed):

    torchrun --standalone --nproc-per-node 2 -m runners.train --num-envs 512
    torchrun --nnodes 2 --node-rank R --nproc-per-node 8 --rdzv-endpoint HOST:29400 \\
        -m runners.train --num-envs 512     # on each machine, R = 0, 1

Each rank steps its own --num-envs envs (2 ranks x 512: 1024 envs per rollout)
with its own seed stream and its share of the machine's cores; rank 0 alone
writes the run folder (checkpoints, config.json, TensorBoard, exports) and holds
its lock. Every rank must be started with the same flags (only --threads may
differ): ranks that differ refuse to start, naming the flags.

Writes to --log-dir: TensorBoard events (every reward term, episode length, fall
rate, forward velocity), checkpoints, config.json (what play.py needs to rebuild
the env), and at the end exported/policy.pt (TorchScript) and
exported/policy.onnx. Iterations count from 0; model_<it>.pt holds the state
after iteration <it>, and is written for every <it> that is a multiple of
--save-interval and for the last iteration (--save-interval 3, 7 iterations:
model_0.pt, model_3.pt, model_6.pt). Checkpoints and config.json are written
atomically: a killed run leaves only complete checkpoints. A folder with
checkpoints belongs to one run: train there again only with --resume
(continuing at <it> + 1) or --overwrite; .rwalk.lock in it marks a run in
progress.
"""

from __future__ import annotations

import contextlib
import dataclasses
import importlib.metadata
import json
import math
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import torch

from rwalk import EnvConfig, ResidualWalkVecEnv, presets
from rwalk.export import export_policy
from rwalk.progress import Progress
from rwalk.runners import distributed
from rwalk.runners.checkpoints import (
    CheckpointError,
    RunSetupError,
    SafeRunner,
    atomic_write_text,
    check_rsl_rl,
    checkpoint_files,
    load_checkpoint,
    newest_checkpoint,
    remove_unfinished_writes,
    run_lock,
)
from rwalk.runners.cli import (
    command,
    flag,
    parse_dataclass,
    require_at_least,
    require_in,
    require_positive,
)
from rwalk.wrappers import RslRlVecEnv

PROG = command("rwalk.runners.train")
"""The command in usage lines and error messages."""


@dataclass(frozen=True)
class Args:
    """Training run. Every field is a command-line flag (--num-envs, ...), checked on creation.

    Raises:
        ValueError: naming the flag, for a value out of its range.
    """

    task: str = field(
        default="residual_walk", metadata={"help": "task: residual_walk or adaptive_gait"}
    )
    num_envs: int = field(
        default=1024,
        metadata={
            "help": "parallel envs (under torchrun: per rank, so P ranks step P times as many)"
        },
    )
    max_iterations: int = field(
        default=300, metadata={"help": "PPO iterations in total, counting those of --resume"}
    )
    max_minutes: float = field(
        default=math.inf, metadata={"help": "stop at a checkpoint after this much wall time"}
    )
    log_dir: str = field(default="logs/rwalk", metadata={"help": "output folder of this run"})
    seed: int = field(
        default=0,
        metadata={
            "help": "seed of the envs and of torch (under torchrun, rank r seeds its envs with "
            "seed + r * (num_envs + its settled-start pool) and torch with seed + r)"
        },
    )
    resume: str = field(
        default="",
        metadata={
            "help": "continue from this checkpoint file, or from the newest checkpoint that "
            "loads in this run folder"
        },
    )
    overwrite: bool = field(
        default=False,
        metadata={
            "help": "train in a --log-dir that holds another run's checkpoints: delete its "
            "model_*.pt files (all but the --resume file) and, unless resuming from it, its "
            "TensorBoard event files"
        },
    )
    robust: bool = field(
        default=True,
        metadata={
            "help": "train for worlds never seen: per-env terrain levels with their curriculum, "
            "randomised physics, pushes, observation noise and a privileged critic "
            "(--no-robust: one rough world at --terrain-scale, as before)"
        },
    )
    terrain_scale: float = field(
        default=1.0, metadata={"help": "--no-robust: roughness of the one rough world, 0..1"}
    )
    save_interval: int = field(
        default=25,
        metadata={"help": "save model_<it>.pt when <it> is a multiple of this, and at the end"},
    )
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
        default=(),
        metadata={
            "help": "observation pieces the policy sees (none: the observation, phase, "
            "lateral_offset and the task's command)"
        },
    )
    command_range: tuple[float, ...] = field(
        default=(),
        metadata={
            "help": "draw each episode's target velocity from LOW HIGH m/s, shown to the "
            "policy as the piece command (none: the gait's step_length / cycle_time)",
            "item": float,
        },
    )
    start_spread: float = field(
        default=0.5,
        metadata={
            "help": "adaptive_gait: episodes start from gait parameters spread by this "
            "fraction of each range (0: the starting gait; residual_walk ignores it)"
        },
    )
    threads: int = field(
        default=0,
        metadata={
            "help": "physics and torch threads (0 = all cores; under torchrun, per rank: "
            "0 = the machine's cores / its ranks)"
        },
    )
    export: bool = field(default=True, metadata={"help": "export TorchScript and ONNX at the end"})
    dist_timeout: float = field(
        default=distributed.DEFAULT_TIMEOUT_S,
        metadata={
            "help": "under torchrun: seconds a rank waits for the others (in any exchange) "
            "before the whole training fails; longer than building the envs or one iteration"
        },
    )

    def __post_init__(self) -> None:
        require_at_least(
            self,
            1,
            "num_envs",
            "max_iterations",
            "save_interval",
            "num_steps_per_env",
            "settle_reuse",
            "max_episode_steps",
            "num_learning_epochs",
            "num_mini_batches",
        )
        require_at_least(self, 0, "settle_steps", "threads", "seed")
        require_positive(self, "reward_scale", "learning_rate", "init_noise_std", "dist_timeout")
        require_positive(self, "max_minutes", finite=False)
        require_at_least(self, 0, "entropy_coef")
        require_in(self, "gamma", 0.0, 1.0, low_open=True)
        require_in(self, "start_spread", 0.0, 1.0)
        require_in(self, "terrain_scale", 0.0, 1.0)
        require_in(self, "settle_pool_fraction", 0.0, 1.0, low_open=True)
        from rwalk.tasks import get_task

        get_task(self.task)  # ValueError listing the known tasks
        if self.command_range and (
            len(self.command_range) != 2 or self.command_range[0] > self.command_range[1]
        ):
            raise ValueError(f"--command-range must be LOW HIGH, got {self.command_range}")
        if not self.hidden_dims or min(self.hidden_dims) < 1:
            raise ValueError(f"--hidden-dims must be sizes >= 1, got {self.hidden_dims}")

    @classmethod
    def from_saved(cls, saved: dict) -> Args:
        """The flags of a run's config.json (``"args"``): flags this version no longer has
        are dropped, and a run saved before ``robust`` existed trained without it."""
        known = {f.name for f in dataclasses.fields(cls)}
        values = {"robust": False} | {k: v for k, v in saved.items() if k in known}
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in values.items()})


def parse_args(argv: list[str] | None = None) -> Args:
    return parse_dataclass(Args, argv, __doc__, prog=PROG)


def env_config(args: Args) -> EnvConfig:
    """The training env: rough world, starts spread over the terrain, pooled settling."""
    return presets.training_config(
        args.task,
        num_envs=args.num_envs,
        robust=args.robust,
        terrain_scale=args.terrain_scale,
        settle_steps=args.settle_steps,
        settle_pool_fraction=args.settle_pool_fraction,
        settle_reuse=args.settle_reuse,
        max_episode_steps=args.max_episode_steps,
        threads=args.threads,
        command_range=tuple(float(v) for v in args.command_range) or None,
        start_spread=args.start_spread,
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
    vec = ResidualWalkVecEnv(args.num_envs, env_config(args), seed=args.seed, task=args.task)
    vec.core.settle_progress = Progress("settling starts", "physics steps")
    pieces = policy_pieces(args, vec.core.task)
    critic = (*pieces, *vec.core.task.privileged())
    return RslRlVecEnv(vec, policy_obs=pieces, critic_obs=critic, reward_scale=args.reward_scale)


def policy_pieces(args: Args, task) -> tuple[str, ...]:
    """The pieces of a run's policy group: --policy-obs, else the observation and the
    task's extra pieces (a robust run's observation counts the torso's x, y from the
    episode's start: on the terrain-levels map, where it is would tell its level)."""
    if args.policy_obs:
        return args.policy_obs
    observation = "observation_from_start" if args.robust else "observation"
    extras = (name for name in task.extras() if name != "command" or args.command_range)
    return (observation, *extras)


def start_as_base_gait(runner) -> None:
    """Zero the actor's output layer: the untrained policy's mean residual is 0, so
    training starts from the base gait (random output weights made the robots
    stumble: white-noise residuals of a few mm at 50 Hz stop the gait)."""
    last = [m for m in runner.alg.get_policy().mlp.modules() if isinstance(m, torch.nn.Linear)][-1]
    with torch.no_grad():
        last.weight.zero_()
        last.bias.zero_()


def resume_point(args: Args) -> tuple[Path, int] | None:
    """The checkpoint --resume names (a file, or a folder's newest that loads) and its iteration.

    Raises:
        FileNotFoundError, CheckpointError: naming the file or folder.
        RunSetupError: if the checkpoint's iteration leaves nothing to train.
    """
    if not args.resume:
        return None
    if Path(args.resume).is_dir():
        path, state = newest_checkpoint(args.resume)
    else:
        path = Path(args.resume)
        state = check_rsl_rl(load_checkpoint(path), path)
    iteration = int(state["iter"])
    if iteration + 1 >= args.max_iterations:
        raise RunSetupError(
            f"--resume {path} holds iteration {iteration}, so --max-iterations "
            f"{args.max_iterations} leaves nothing to train (iterations count from 0); "
            f"pass --max-iterations {iteration + 2} or more"
        )
    saved = path.parent / "config.json"
    if saved.is_file():
        trained = Args.from_saved(json.loads(saved.read_text())["args"])
        if trained.robust != args.robust:
            flag = "--robust" if trained.robust else "--no-robust"
            raise RunSetupError(
                f"--resume {path}: its run trained with {flag} (its {saved}), and the robust "
                f"training's policy and critic read other pieces; pass {flag} to resume it"
            )
    return path, iteration


def claim_log_dir(args: Args, log_dir: Path, resume: tuple[Path, int] | None) -> None:
    """Make ``log_dir`` this run's own: refuse one that holds another run's checkpoints
    (or, resuming from it, newer ones that would be overwritten) unless --overwrite, which
    deletes them; delete temporary files of killed writes. Call while holding its lock.

    Raises:
        RunSetupError: naming the folder and the flags that would allow the run.
    """
    resumed, resumed_it = resume if resume else (None, -1)
    own = resumed is not None and resumed.parent.resolve() == log_dir.resolve()
    if own and Path(args.resume).is_dir():  # resumed from its newest checkpoint that loads
        old = []
    else:  # with a file in it, those newer than the file
        old = [path for it, path in checkpoint_files(log_dir) if not own or it > resumed_it]
    if old and args.overwrite:
        events = [] if own else list(log_dir.glob("events.out.tfevents.*"))
        for path in [*old, *events]:
            path.unlink()
        print(f"--overwrite: deleted {len(old)} checkpoints and {len(events)} event files")
    elif old and own:
        raise RunSetupError(
            f"--resume {resumed} is not the newest checkpoint in {log_dir} (there is "
            f"{old[-1].name}): training on from it would overwrite the newer ones; pass "
            f"--overwrite to delete them, or --resume {log_dir} to continue from the newest"
        )
    elif old:
        raise RunSetupError(
            f"--log-dir {log_dir} already holds another run's checkpoints ({old[0].name} .. "
            f"{old[-1].name}); pass --resume {log_dir} to continue that run, --overwrite to "
            "replace it, or choose another --log-dir"
        )
    for path in remove_unfinished_writes(log_dir):
        print(f"deleted {path.name}, the unfinished write of a killed run")


PER_RANK_FLAGS = ("threads",)
"""Flags the ranks of one training may set differently: a machine's own resources."""
SETUP_ERRORS = (CheckpointError, FileNotFoundError, RunSetupError)
"""Errors of a run that cannot start as asked: rank 0's reach every rank (same message)."""


def run_settings(args: Args) -> dict[str, Any]:
    """What every rank of a training must share: its flags (but ``PER_RANK_FLAGS``) and the
    versions of the libraries that compute (JSON-able; keys are the flags and package names)."""
    flags = {flag(k): v for k, v in dataclasses.asdict(args).items() if k not in PER_RANK_FLAGS}
    versions = {
        "torch": torch.__version__,
        "rsl-rl-lib": importlib.metadata.version("rsl-rl-lib"),
        "mujoco": mujoco.__version__,
        "numpy": np.__version__,
    }
    return flags | versions


def rank_args(args: Args, group: distributed.Group) -> Args:
    """The flags of this rank's envs. One process: ``args``. Rank r of a group: seed
    ``args.seed + r * (num_envs + pool)``, so that its envs and settled-start pool entries
    (keyed seed + i, then seed + num_envs + j; ``rwalk.core``) share no key with another
    rank's; --threads 0 becomes the machine's cores divided among its ranks."""
    if not group.distributed:
        return args
    stride = args.num_envs + env_config(args).settle_pool
    threads = args.threads or distributed.default_threads(group)
    return dataclasses.replace(args, seed=args.seed + group.rank * stride, threads=threads)


def train(args: Args) -> Path:
    """Run the training; returns the last checkpoint's path.

    Under torchrun (WORLD_SIZE > 1) every rank runs this and joins the gloo group
    first; a single process sets nothing up.

    Raises:
        FileNotFoundError, CheckpointError, RunSetupError: before anything is
            trained, naming the file, folder or flags at fault (under torchrun,
            rank 0's, on every rank).
        distributed.GroupError: ranks started with different flags or torchrun
            variables that make no group (naming them).
        RuntimeError: under torchrun, another rank died or hung past --dist-timeout
            (``distributed.is_group_failure``).
    """
    clock = time.perf_counter()  # the wall-time budget counts from here, env building included
    group = distributed.Group.from_env()
    distributed.join(group, args.dist_timeout)
    try:
        distributed.check_same_settings(group, run_settings(args))
        return _train(args, group, clock)
    finally:
        distributed.leave()


def _claim_run(args: Args, group: distributed.Group, stack: contextlib.ExitStack):
    """Rank 0 checks --resume, takes the run folder's lock (held until ``stack`` closes) and
    claims the folder; every rank gets the resume point (rank 0's) or rank 0's error, and
    the checkpoint's bytes (None for one process: it reads the file itself)."""
    resume, failure = None, None
    if group.main:
        try:
            resume = resume_point(args)
            stack.enter_context(run_lock(Path(args.log_dir)))
            claim_log_dir(args, Path(args.log_dir), resume)
        except Exception as error:  # the other ranks wait to hear of it
            failure = error
    distributed.raise_if_failed(group, failure, SETUP_ERRORS)
    if not group.distributed:
        return resume, None
    shared = distributed.broadcast_json(group, resume and [str(resume[0]), resume[1]])
    if shared is None:
        return None, None
    data = distributed.broadcast_bytes(group, resume[0].read_bytes() if resume else None)
    return (Path(shared[0]), int(shared[1])), data


def _train(args: Args, group: distributed.Group, clock: float) -> Path:
    say = print if group.main else lambda *_, **__: None  # rank 0 speaks for the group
    log_dir = Path(args.log_dir)
    with contextlib.ExitStack() as stack:  # rank 0 holds the lock until the run ends
        resume, data = _claim_run(args, group, stack)
        mine = rank_args(args, group)
        torch.manual_seed(args.seed + group.rank)
        if mine.threads:  # the process's share of the cores, for learning too
            torch.set_num_threads(mine.threads)
        if group.distributed:
            print(
                f"[rwalk] rank {group.rank} of {group.world_size} (pid {os.getpid()}): "
                f"{mine.num_envs} envs seeded from {mine.seed}, {mine.threads} threads",
                flush=True,
            )
        say(f"building {args.num_envs} envs (settling their starts) ...", flush=True)
        env = make_env(mine)
        say(f"  ready in {time.perf_counter() - clock:.1f} s", flush=True)
        runner = SafeRunner(
            env, rsl_rl_config(args), log_dir=str(log_dir) if group.main else None, device="cpu"
        )
        hashes = os.environ.get(distributed.PARAMETER_HASHES_ENV)
        if hashes:
            distributed.record_parameter_hashes(runner, hashes, group)
        if resume is None:
            start_as_base_gait(runner)  # learn() then broadcasts rank 0's parameters
        else:  # every rank loads rank 0's file
            runner.load(str(resume[0]), data=data)
            if env.core.terrain_map is not None:
                env.core.reset()  # every env restarts on its level of the resumed curriculum
            runner.current_learning_iteration += 1  # continue after the saved iteration
            say(f"resumed from {resume[0]}: next iteration {runner.current_learning_iteration}")
        if group.main:
            config = {"args": dataclasses.asdict(args), "env": dataclasses.asdict(env.env.config)}
            atomic_write_text(log_dir / "config.json", json.dumps(config, indent=2))

        first = runner.current_learning_iteration
        budget = args.max_minutes * 60.0
        learning_since = time.perf_counter()  # per-iteration time excludes building the envs
        while runner.current_learning_iteration < args.max_iterations:
            it = runner.current_learning_iteration
            # One learn() call up to the next checkpoint: rsl-rl saves the multiples of
            # save_interval in its loop and the call's last iteration after it.
            last = min(-(-it // args.save_interval) * args.save_interval, args.max_iterations - 1)
            runner.learn(num_learning_iterations=last + 1 - it, init_at_random_ep_len=it == first)
            if runner.logger.writer is not None:  # rank 0's; learn() opens one each call
                runner.logger.writer.close()
            checkpoint = log_dir / f"model_{last}.pt"
            runner.current_learning_iteration = last + 1  # learn() leaves it at its last one
            done = last + 1 - first
            now = time.perf_counter()
            elapsed = now - clock
            per_iteration = (now - learning_since) / done
            left = args.max_iterations - (last + 1)
            eta = min(left * per_iteration, max(budget - elapsed, 0.0))
            say(
                f"[rwalk] iteration {last + 1}/{args.max_iterations}, "
                f"{elapsed / 60:.1f} min elapsed, ETA {eta / 60:.1f} min, "
                f"checkpoint {checkpoint}",
                flush=True,
            )
            # Rank 0's clock decides for every rank: all stop after the same iteration.
            over = elapsed + per_iteration * min(args.save_interval, left) > budget
            if distributed.agree(group, over):
                say(f"[rwalk] stopping: the {args.max_minutes:g}-minute budget is reached")
                break

        if args.export and group.main:
            jit_path, onnx_path = export_policy(runner, log_dir / "exported")
            print(f"[rwalk] exported {jit_path} and {onnx_path} (layout: policy.json)")
    return checkpoint


def main(argv: list[str] | None = None) -> None:
    """The ``rwalk-train`` command; a run that cannot start exits with a one-line error
    (under torchrun, naming the rank), and so does a rank whose group failed."""
    args = parse_args(argv)
    where = ""
    try:
        group = distributed.Group.from_env()
        if group.distributed:
            where = f"rank {group.rank} of {group.world_size}: "
        train(args)
    except (CheckpointError, FileNotFoundError, RunSetupError, distributed.GroupError) as error:
        raise SystemExit(f"{PROG}: error: {where}{error}") from None
    except RuntimeError as error:
        if not (where and distributed.is_group_failure(error)):
            raise
        raise SystemExit(
            f"{PROG}: error: {where}the training's process group failed: another rank died, "
            f"or did not answer within --dist-timeout {args.dist_timeout:g} s "
            f"({type(error).__name__}: {error})"
        ) from None


if __name__ == "__main__":
    main()
