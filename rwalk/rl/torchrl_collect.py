"""Where the TorchRL trainer gets its frames: its env, and one in-process ``Collector``
or ``--collectors K`` workers on one of TorchRL's collector backends.

    --collectors 1 (default)            torchrl.collectors.Collector, envs in this process
    --collectors K --backend process    Collector(backend="process") -> MultiSyncCollector:
                                        K local processes, weights in shared memory
    --collectors K --backend distributed
                                        Collector(backend="distributed") -> DistributedCollector:
                                        K processes joined by torch.distributed (gloo),
                                        launched here (launcher "mp")
    --collectors K --backend ray        Collector(backend="ray") -> RayCollector: K Ray actors
                                        (the ``ray`` extra: pip install -e ".[ray]")

The env (``make_env``) is the training's envs (``TorchRLTraining``'s env: by
default the robust world) with the policy's and the critic's observation groups of
the one rule (``rwalk.rl.config.observation_groups``) as the keys ``policy`` (with
observation noise) and ``critic`` (exact), each normalised (``ObservationNorm``),
and the reward scaled. Every worker builds its own env from a picklable
``WorkerEnv``: ``--num-envs`` envs (the count is per worker), env seeds
``seed + worker * (num_envs + pool) ...`` (no two workers' envs or settled-start pool
entries share a key), its own torch seed for the action noise, and its
own thread budget (physics and torch): ``--threads``, or ``cores // K`` when that is
0. All workers normalise with the statistics this process measured once, so the
policy sees one scale and the checkpoint holds it. Collection is synchronous: each
iteration gathers one rollout of ``--num-steps-per-env`` steps from every worker,
stacked into a batch of shape (K, num_envs, num_steps_per_env).

Each env also carries its curricula (the terrain levels and command weights,
``Core.curriculum_state``) in its transforms' ``state_dict`` (``Curricula``), so that
a collector's own ``state_dict()`` holds every local worker's (``curricula``) and a
resumed run builds each worker's env on its saved levels (``make_env``'s
``curricula``). TorchRL's distributed and Ray collectors give no ``state_dict``: with
those backends a resumed run's curricula start again.
"""

from __future__ import annotations

import socket
from dataclasses import dataclass

import torch
from torch import Tensor
from torchrl.collectors import BaseCollector, Collector, MultiSyncCollector
from torchrl.envs import Compose, ObservationNorm, RewardScaling, Transform, TransformedEnv

from rwalk.envs.torchrl_env import BatchedEnv
from rwalk.rl.checkpoints import RunSetupError
from rwalk.rl.config import observation_groups
from rwalk.rl.torchrl_config import TorchRLConfig, TorchRLTraining
from rwalk.threads import cores

GROUPS = ("policy", "critic")
"""The env's keys the actor (``policy``) and the critic (``critic``) read."""
NORM_STEPS = 20
"""Random-action steps whose observations set the normalisation."""

Norms = dict[str, tuple[Tensor, Tensor]]
"""(loc, scale) of each normalised key: ``(x - loc) / scale``. Shapes: (D,), (D,)."""
State = dict[str, Tensor]
"""An env's curricula: ``Core.curriculum_state()`` (empty where it has none)."""


#: Older name of ``rwalk.threads.cores``.
available_cores = cores


def worker_threads(collectors: int, threads: int) -> int:
    """Physics and torch threads of each of ``collectors`` workers: ``threads`` when
    given (> 0), else an equal share of the cores, at least 1."""
    return threads if threads > 0 else max(1, cores() // collectors)


def measure_norms(env: BatchedEnv, keys: tuple[str, ...] = GROUPS) -> Norms:
    """Mean and standard deviation of each of ``keys`` over ``NORM_STEPS`` steps of
    random actions from a reset (one rollout for every key); scales at least float32's
    eps, as ``ObservationNorm.init_stats`` has them."""
    rollout = env.rollout(max_steps=NORM_STEPS)  # (N, T)
    eps = torch.finfo(torch.float32).eps
    return {
        key: (rollout[key].mean(dim=(0, 1)), rollout[key].std(dim=(0, 1)).clamp_min(eps))
        for key in keys
    }


def make_env(
    setup: TorchRLTraining,
    reward_scale: float,
    *,
    seed: int,
    threads: int,
    norms: Norms | None = None,
    curricula: State | None = None,
) -> TransformedEnv:
    """The training env: ``setup.num_envs`` envs of ``setup``'s world with the keys
    ``policy`` and ``critic`` (their observation groups, normalised), scaled reward, and
    its curricula in its ``state_dict`` (``Curricula``).

    Args:
        setup: the training's envs (task, count, world).
        reward_scale: PPO sees ``reward * reward_scale``.
        seed: env seed (env i starts like a single env seeded ``seed + i``).
        threads: physics threads (0 = all cores).
        norms: (loc, scale) of each of ``GROUPS``, each shaped like its key (D,); None
            measures them on this env (``measure_norms``).
        curricula: a resumed run's curricula of these envs (``Core.curriculum_state``),
            loaded before the first reset; None: they start at the start level.

    Raises:
        ValueError: naming the field, if ``curricula`` is not what a run saved.
    """
    base = BatchedEnv(
        setup.num_envs,
        setup.env_config(threads),
        seed=seed,
        task=setup.task,
        groups=lambda task: observation_groups(task, setup.env),
    )
    if curricula is not None:
        _note(base.core.load_curriculum_state(curricula))
    norms = measure_norms(base) if norms is None else norms
    normalise = [
        ObservationNorm(loc=loc.clone(), scale=scale.clone(), in_keys=[key], standard_normal=True)
        for key, (loc, scale) in norms.items()
    ]
    scale = RewardScaling(loc=0.0, scale=reward_scale)
    return TransformedEnv(base, Compose(*normalise, scale, Curricula()))


def _note(note: str | None) -> None:
    if note:
        print(f"[torchrl] note: {note}", flush=True)


class Curricula(Transform):
    """Keeps its env's curricula (``Core.curriculum_state``: terrain levels, command
    weights) as the transform's extra state, as ``VecNorm`` keeps its statistics: a
    ``TransformedEnv``'s ``state_dict`` is its transforms', so the env's, and a
    collector's (a worker's too), hold them; ``load_state_dict`` goes on from them.
    Changes no key of the data."""

    def __init__(self) -> None:
        super().__init__(in_keys=[], out_keys=[])

    def _core(self):
        return self.parent.base_env.core

    def get_extra_state(self) -> State:
        return self._core().curriculum_state()

    def set_extra_state(self, state: State) -> None:
        _note(self._core().load_curriculum_state(state))


def curricula(collector: BaseCollector) -> list[State] | None:
    """Each local env's curricula, worker by worker (``Curricula``'s extra state), from
    the collector's own ``state_dict()``; None where its backend gives none (distributed,
    Ray)."""
    if isinstance(collector, MultiSyncCollector):
        state = collector.state_dict()
        envs = [state[f"worker{i}"]["env_state_dict"] for i in range(collector.num_workers)]
    elif isinstance(collector, Collector):
        envs = [collector.state_dict()["env_state_dict"]]
    else:
        return None
    # Curricula is the one transform of make_env's with extra state
    return [next(v for k, v in env.items() if k.endswith("_extra_state")) for env in envs]


def resumed_curricula(saved: list[State] | None, workers: int) -> list[State | None]:
    """Each of ``workers`` envs' curricula to go on from: worker w takes the saved
    worker w mod (those saved) (the same where the count is the run's); None each where
    the checkpoint holds none (written before the curricula were kept, or by a
    distributed or Ray run), with a line for the log."""
    if not saved:
        _note("the checkpoint holds no curricula (terrain levels, command weights): "
              "they start again")  # fmt: skip
        return [None] * workers
    if len(saved) != workers:
        _note(f"the checkpoint holds the curricula of {len(saved)} collector workers, "
              f"this run has {workers}: worker w goes on from saved worker w mod "
              f"{len(saved)}")  # fmt: skip
    return [saved[w % len(saved)] for w in range(workers)]


def norm_stats(env: TransformedEnv) -> Norms:
    """(loc, scale) of each key ``env`` normalises (``make_env``'s), detached."""
    return {
        t.in_keys[0]: (t.loc.detach(), t.scale.detach())
        for t in env.transform
        if isinstance(t, ObservationNorm)
    }


@dataclass(frozen=True)
class WorkerEnv:
    """Picklable env constructor of collector worker ``worker``; called in the worker.

    Sets the worker's torch threads and seed, then builds ``make_env`` with env seed
    ``first_seed + worker * (num_envs + pool)``: worker w's envs and settled-start pool
    entries (keyed seed + i, then seed + num_envs + j; ``rwalk.starts``) share no key with
    another worker's, as rwalk-train's ranks. ``threads`` physics threads.
    """

    setup: TorchRLTraining
    """The envs each worker steps (``num_envs`` of them)."""
    reward_scale: float
    """PPO sees ``reward * reward_scale``."""
    first_seed: int
    """The run's seed: worker 0's envs' first."""
    worker: int
    """This worker's index, 0 .. K-1."""
    threads: int
    """Physics and torch threads of this worker."""
    norms: Norms
    """The normalisation this process measured, of each of ``GROUPS``."""
    curricula: State | None = None
    """A resumed run's curricula of this worker's envs; None: they start again."""

    @property
    def seed(self) -> int:
        return self.first_seed + self.worker * (self.setup.num_envs + self.setup.env.settle_pool)

    def __call__(self) -> TransformedEnv:
        torch.set_num_threads(self.threads)
        torch.manual_seed(self.seed)  # the worker's own stream of action noise
        return make_env(self.setup, self.reward_scale, seed=self.seed, threads=self.threads,
                        norms=self.norms, curricula=self.curricula)  # fmt: skip


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


def make_collector(
    env: TransformedEnv,
    policy: torch.nn.Module,
    setup: TorchRLTraining,
    ppo: TorchRLConfig,
    *,
    seed: int,
    threads: int,
    iterations: int,
    curricula: list[State | None] | None = None,
) -> BaseCollector:
    """The run's collector: ``iterations`` synchronous batches.

    With one collector on the process backend, a ``Collector`` steps ``env`` here
    (batches of shape (num_envs, num_steps_per_env)), its envs going on from
    ``curricula[0]``. Otherwise K workers each build their own env (``WorkerEnv`` of
    ``setup``, seeds from ``seed``, ``threads`` threads or a share of the cores)
    normalised with ``env``'s statistics; batches have shape (K, num_envs,
    num_steps_per_env); worker w's envs go on from ``curricula[w]``. ``curricula``: a
    resumed run's (``resumed_curricula``); None: none. Send new weights with
    ``update_policy_weights_()`` after each update.
    """
    frames = setup.num_envs * ppo.num_steps_per_env  # per worker and batch
    saved = curricula or [None] * ppo.collectors
    if ppo.collectors == 1 and ppo.backend == "process":
        if saved[0] is not None:  # before the collector's first reset
            _note(env.base_env.core.load_curriculum_state(saved[0]))
        return Collector(
            env,
            policy,
            frames_per_batch=frames,
            total_frames=frames * iterations,
            auto_register_policy_transforms=False,  # the MLP policy keeps no state
        )
    k = ppo.collectors
    per_worker = worker_threads(k, threads)
    norms = norm_stats(env)
    makers = [WorkerEnv(setup, ppo.reward_scale, seed, w, per_worker, norms, saved[w])
              for w in range(k)]  # fmt: skip
    worker_kwargs = {"auto_register_policy_transforms": False}
    if ppo.backend == "process":
        options = {
            **worker_kwargs,
            "num_threads": torch.get_num_threads(),  # this process learns while workers wait
            "num_sub_threads": per_worker,
            "cat_results": "stack",
        }
    elif ppo.backend == "distributed":
        options = {
            "launcher": "mp",  # local processes; Slurm would be "submitit"
            "backend": "gloo",
            "tcp_port": _free_port(),
            "collector_kwargs": worker_kwargs,
        }
    else:
        options = {"collector_kwargs": worker_kwargs, "remote_configs": {"num_cpus": per_worker}}
    # DistributedCollector builds worker 0's env here once (to learn the batch layout):
    # keep this process's torch threads and random stream as they were.
    threads_here = torch.get_num_threads()
    with torch.random.fork_rng(devices=[]):
        collector = Collector(
            makers,
            policy,
            backend=ppo.backend,
            num_collectors=k,
            sync=True,
            frames_per_batch=k * frames,
            total_frames=k * frames * iterations,
            backend_options=options,
        )
    torch.set_num_threads(threads_here)
    collector.update_policy_weights_()  # every worker starts from this process's weights
    return collector
