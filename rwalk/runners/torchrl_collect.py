"""Where ``rwalk-train-torchrl`` gets its frames: one in-process ``Collector``, or
``--collectors K`` workers on one of TorchRL's collector backends.

    --collectors 1 (default)            torchrl.collectors.Collector, envs in this process
    --collectors K --backend process    Collector(backend="process") -> MultiSyncCollector:
                                        K local processes, weights in shared memory
    --collectors K --backend distributed
                                        Collector(backend="distributed") -> DistributedCollector:
                                        K processes joined by torch.distributed (gloo),
                                        launched here (launcher "mp")
    --collectors K --backend ray        Collector(backend="ray") -> RayCollector: K Ray actors
                                        (the ``ray`` extra: pip install -e ".[ray]")

Every worker builds its own batched env from a picklable ``WorkerEnv``: ``--num-envs``
envs (the count is per worker), env seeds ``seed + worker * num_envs ...`` so that no two
envs share a start, its own torch seed for the action noise, and its own thread budget
(physics and torch): ``--threads``, or ``cores // K`` when that is 0. All workers
normalise observations with the statistics this process measured once, so the policy
sees one scale and the checkpoint holds it. Collection is synchronous: each iteration
gathers one rollout of ``--num-steps-per-env`` steps from every worker, stacked into a
batch of shape (K, num_envs, num_steps_per_env).
"""

from __future__ import annotations

import os
import socket
from dataclasses import dataclass
from typing import TYPE_CHECKING

import torch
from torchrl.collectors import BaseCollector, Collector
from torchrl.envs import CatTensors, Compose, ObservationNorm, RewardScaling, TransformedEnv

from rwalk import ResidualWalkVecEnv, presets
from rwalk.rl.checkpoints import RunSetupError

if TYPE_CHECKING:
    from rwalk.runners.train_torchrl import Args

BACKENDS = ("process", "ray", "distributed")
"""Values of ``--backend``."""


def available_cores() -> int:
    """CPU cores this process may run on (its affinity mask where the OS has one)."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


def worker_threads(collectors: int, threads: int) -> int:
    """Physics and torch threads of each of ``collectors`` workers: ``threads`` when
    given (> 0), else an equal share of the cores, at least 1."""
    return threads if threads > 0 else max(1, available_cores() // collectors)


def make_env(
    args: Args,
    *,
    seed: int | None = None,
    threads: int | None = None,
    obs_norm: tuple[torch.Tensor, torch.Tensor] | None = None,
) -> TransformedEnv:
    """The training env: ``args.num_envs`` envs with the policy's observation
    ``policy_obs`` (the env's keys concatenated and normalised) and scaled reward.

    Args:
        args: the run (task, num_envs, settle_steps, reward_scale; seed and threads
            unless given here).
        seed: env seed (env i starts like a single env seeded ``seed + i``).
        threads: physics threads (0 = all cores).
        obs_norm: (loc, scale) of the observation normalisation, each shaped like
            ``policy_obs`` (obs_dim,); None measures them on 20 steps of this env.
    """
    seed = args.seed if seed is None else seed
    threads = args.threads if threads is None else threads
    config = presets.training_config(
        args.task, num_envs=args.num_envs, threads=threads, settle_steps=args.settle_steps
    )
    base = ResidualWalkVecEnv(args.num_envs, config, seed=seed, task=args.task)
    keys = ["observation", *base.extras]  # the spec observation and the task's extra pieces
    if obs_norm is None:
        norm = ObservationNorm(in_keys=["policy_obs"], standard_normal=True)
    else:
        loc, scale = obs_norm
        norm = ObservationNorm(
            loc=loc.clone(), scale=scale.clone(), in_keys=["policy_obs"], standard_normal=True
        )
    env = TransformedEnv(
        base,
        Compose(
            CatTensors(keys, "policy_obs", del_keys=False),
            norm,
            RewardScaling(loc=0.0, scale=args.reward_scale),
        ),
    )
    if obs_norm is None:
        env.transform[1].init_stats(num_iter=20, reduce_dim=(0, 1), cat_dim=1)
    return env


@dataclass(frozen=True)
class WorkerEnv:
    """Picklable env constructor of collector worker ``worker``; called in the worker.

    Sets the worker's torch threads and seed, then builds ``make_env`` with env seed
    ``seed + worker * num_envs`` (worker w's envs take seeds w*N .. w*N + N-1 past
    ``--seed``) and ``threads`` physics threads.
    """

    args: Args
    worker: int
    threads: int
    obs_loc: torch.Tensor
    """Shape: (obs_dim,)."""
    obs_scale: torch.Tensor
    """Shape: (obs_dim,)."""

    @property
    def seed(self) -> int:
        return self.args.seed + self.worker * self.args.num_envs

    def __call__(self) -> TransformedEnv:
        torch.set_num_threads(self.threads)
        torch.manual_seed(self.seed)  # the worker's own stream of action noise
        return make_env(
            self.args, seed=self.seed, threads=self.threads, obs_norm=(self.obs_loc, self.obs_scale)
        )


def require_backend(backend: str) -> None:
    """Fail early, in one line, when ``backend`` needs what is not installed.

    Raises:
        RunSetupError: ray not importable for "ray"; torch.distributed without gloo
            for "distributed".
    """
    if backend == "ray":
        try:
            import ray  # noqa: F401
        except ImportError:
            raise RunSetupError(
                '--backend ray needs Ray, which is not installed: pip install -e ".[ray]"'
            ) from None
    if backend == "distributed" and not (
        torch.distributed.is_available() and torch.distributed.is_gloo_available()
    ):
        raise RunSetupError("--backend distributed needs torch.distributed with gloo")


class WorkerDied(RuntimeError):
    """A collector worker process has exited while the run still needs it."""


def check_workers(collector: BaseCollector) -> None:
    """Raise if a local worker process of ``collector`` has exited.

    Call it before ``update_policy_weights_()``: TorchRL 0.14's process backend waits
    for every worker's acknowledgement of new weights without a timeout, so a dead
    worker would hang the run there. (While collecting, TorchRL checks by itself.)

    Raises:
        WorkerDied: naming the worker and its exit code.
    """
    # procs: MultiCollector's workers; jobs: DistributedCollector's with launcher "mp".
    workers = getattr(collector, "procs", None) or getattr(collector, "jobs", None) or []
    for i, worker in enumerate(workers):
        if hasattr(worker, "is_alive") and not worker.is_alive():
            raise WorkerDied(
                f"collector worker {i} exited (exit code {worker.exitcode}); the run stops"
            )


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("localhost", 0))
        return s.getsockname()[1]


def make_collector(args: Args, env: TransformedEnv, policy: torch.nn.Module) -> BaseCollector:
    """The run's collector: ``--max-iterations`` synchronous batches.

    With one collector on the process backend, a ``Collector`` steps ``env`` here
    (batches of shape (num_envs, num_steps_per_env)). Otherwise K workers each build
    their own env (``WorkerEnv``) normalised with ``env``'s statistics; batches have
    shape (K, num_envs, num_steps_per_env). Send new weights with
    ``update_policy_weights_()`` after each update.
    """
    frames = args.num_envs * args.num_steps_per_env  # per worker and batch
    if args.collectors == 1 and args.backend == "process":
        return Collector(
            env,
            policy,
            frames_per_batch=frames,
            total_frames=frames * args.max_iterations,
            auto_register_policy_transforms=False,  # the MLP policy keeps no state
        )
    k = args.collectors
    threads = worker_threads(k, args.threads)
    norm = env.transform[1]
    makers = [WorkerEnv(args, w, threads, norm.loc.detach(), norm.scale.detach()) for w in range(k)]
    worker_kwargs = {"auto_register_policy_transforms": False}
    if args.backend == "process":
        options = {
            **worker_kwargs,
            "num_threads": torch.get_num_threads(),  # this process learns while workers wait
            "num_sub_threads": threads,
            "cat_results": "stack",
        }
    elif args.backend == "distributed":
        options = {
            "launcher": "mp",  # local processes; Slurm would be "submitit"
            "backend": "gloo",
            "tcp_port": _free_port(),
            "collector_kwargs": worker_kwargs,
        }
    else:
        options = {"collector_kwargs": worker_kwargs, "remote_configs": {"num_cpus": threads}}
    # DistributedCollector builds worker 0's env here once (to learn the batch layout):
    # keep this process's torch threads and random stream as they were.
    threads_here = torch.get_num_threads()
    with torch.random.fork_rng(devices=[]):
        collector = Collector(
            makers,
            policy,
            backend=args.backend,
            num_collectors=k,
            sync=True,
            frames_per_batch=k * frames,
            total_frames=k * frames * args.max_iterations,
            backend_options=options,
        )
    torch.set_num_threads(threads_here)
    collector.update_policy_weights_()  # every worker starts from this process's weights
    return collector
