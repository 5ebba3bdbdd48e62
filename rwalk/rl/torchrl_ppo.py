"""PPO built from TorchRL's own parts on the batched env: the TorchRL trainer.

``train(args)`` runs what ``rwalk-train-torchrl`` asks for (a
``TorchRLTraining``): a collector (``rwalk.rl.torchrl_collect``) steps the
training's envs (by default the robust world, as ``rwalk-train``'s);
GAE computes advantages; ClipPPOLoss trains a TanhNormal actor on the key
``policy`` (the policy's observation group, with observation noise) and a value
network on ``critic`` (the critic's group: in the robust world with the privileged
pieces), each normalised, on minibatches from a replay buffer.

Writes to ``run.log_dir`` under its lock (``rwalk.rl.checkpoints.run_lock``):
config.json (its record, ``"trainer": "torchrl"``), and checkpoints
``torchrl_<n>.pt`` (the state after <n> iterations, every ``run.save_interval``, at
the end and when ``run.max_minutes`` is spent; marked ``"trainer": "torchrl"``; with
each local collector worker's curricula, ``rwalk.rl.torchrl_collect.curricula``),
atomically. Prints one progress line per iteration (with that iteration's
frames/s, overall and while collecting).
"""

from __future__ import annotations

import contextlib
import dataclasses
import time
from pathlib import Path
from typing import Any

import torch
from tensordict.nn import NormalParamExtractor, TensorDictModule
from torch import nn
from torchrl.collectors import BaseCollector
from torchrl.data import LazyTensorStorage, ReplayBuffer
from torchrl.data.replay_buffers.samplers import SamplerWithoutReplacement
from torchrl.envs import ObservationNorm, TransformedEnv
from torchrl.modules import MLP, ProbabilisticActor, TanhNormal, ValueOperator
from torchrl.objectives import ClipPPOLoss
from torchrl.objectives.value import GAE

from rwalk.constants import OBS_LINVEL
from rwalk.rl.checkpoints import (
    CheckpointError,
    RunSetupError,
    checked_iteration,
    claim_log_dir,
    load_checkpoint,
    newest_checkpoint,
    quote,
    require_trainer,
    run_lock,
    save_checkpoint,
)
from rwalk.rl.config import RunSettings, resume_conflict
from rwalk.rl.legacy import as_training
from rwalk.rl.record import read_record, write_record
from rwalk.rl.torchrl_collect import (
    check_workers,
    curricula,
    make_collector,
    make_env,
    require_backend,
    resumed_curricula,
)
from rwalk.rl.torchrl_config import TorchRLConfig, TorchRLTraining
from rwalk.threads import SharedCores

__all__ = ["TRAINER", "make_modules", "train"]

TRAINER = "torchrl"
"""The ``"trainer"`` of this trainer's checkpoints and config.json."""


def make_modules(
    ppo: TorchRLConfig, env: TransformedEnv
) -> tuple[ProbabilisticActor, ValueOperator]:
    """The actor (TanhNormal over the actions, from the key ``policy``) and the value
    network (from ``critic``), MLPs of ``ppo.hidden_dims``. The actor starts as the base
    gait: its mean residual is 0, its pre-tanh std ``ppo.init_noise_std``."""
    policy_dim = env.observation_spec["policy"].shape[-1]
    critic_dim = env.observation_spec["critic"].shape[-1]
    act_dim = env.action_spec.shape[-1]
    cells = list(ppo.hidden_dims)
    body = MLP(in_features=policy_dim, out_features=2 * act_dim, num_cells=cells)
    last = body[-1]
    with torch.no_grad():  # start as the base gait: zero mean residual
        last.weight.zero_()
        last.bias.zero_()
    # softplus biased so that a zero pre-activation gives the initial std
    extractor = NormalParamExtractor(scale_mapping=f"biased_softplus_{ppo.init_noise_std}")
    actor = ProbabilisticActor(
        TensorDictModule(
            nn.Sequential(body, extractor), in_keys=["policy"], out_keys=["loc", "scale"]
        ),
        in_keys=["loc", "scale"],
        spec=env.action_spec,
        distribution_class=TanhNormal,
        distribution_kwargs={"low": -1.0, "high": 1.0},
        return_log_prob=True,
    )
    critic = ValueOperator(
        MLP(in_features=critic_dim, out_features=1, num_cells=cells), in_keys=["critic"]
    )
    return actor, critic


def check_torchrl(loaded: dict[str, Any], path) -> dict[str, Any]:
    """``loaded`` (from ``load_checkpoint(path)``) if rwalk-train-torchrl wrote it: its
    iteration, models, optimizer and normalisations, each of the right type.

    Raises:
        CheckpointError: naming the file and the field.
    """
    require_trainer(loaded, path, TRAINER, "rwalk-train-torchrl")
    checked_iteration(loaded, "iteration", path)
    for key in ("actor", "critic", "optimizer", "obs_norm", "critic_norm"):
        if not isinstance(loaded.get(key), dict):
            raise CheckpointError(f"checkpoint {str(path)!r}: {key!r} must be a dict of states")
    for key in ("obs_norm", "critic_norm"):
        if not all(isinstance(loaded[key].get(k), torch.Tensor) for k in ("loc", "scale")):
            raise CheckpointError(f"checkpoint {str(path)!r}: {key!r} needs tensors loc, scale")
    saved = loaded.get("curricula", [])  # older checkpoints: none
    if not (isinstance(saved, list) and all(_integer_tensors(env) for env in saved)):
        raise CheckpointError(f"checkpoint {str(path)!r}: 'curricula' must be a list of "
                              f"dicts of integer tensors, one per collector worker")  # fmt: skip
    return loaded


def _integer_tensors(state: Any) -> bool:
    return isinstance(state, dict) and all(
        isinstance(v, torch.Tensor) and not v.is_floating_point() and not v.is_complex()
        for v in state.values()
    )


def resume_point(args: TorchRLTraining):
    """The torchrl checkpoint --resume names (a file, or a folder's newest that loads), its
    contents, and the training to go on with (the run's own record, with this command's
    run settings and --num-envs; a field of ``args`` that differs from the record's is
    refused: ``rwalk.rl.config.resume_conflict``).

    Returns:
        (path, contents, args), or None without --resume.

    Raises:
        FileNotFoundError, CheckpointError, ConfigError, ResumeConflict: naming the file,
            folder or flag.
        RunSetupError: if the checkpoint leaves nothing to train.
    """
    run = args.run
    if not run.resume:
        return None
    if Path(run.resume).is_dir():
        path, state = newest_checkpoint(run.resume, trainer=TRAINER, check=check_torchrl)
    else:
        path = Path(run.resume)
        state = check_torchrl(load_checkpoint(path), path)
    done = state["iteration"]
    if done >= run.max_iterations:
        raise RunSetupError(
            f"--resume {path} holds {done} iterations, so --max-iterations "
            f"{run.max_iterations} leaves nothing to train; pass --max-iterations "
            f"{done + 1} or more"
        )
    config = path.parent / "config.json"
    if config.is_file():
        record = read_record(config, TRAINER, TorchRLTraining)
        resume_conflict(args, record, path, config)
        args = dataclasses.replace(record, run=run, num_envs=args.num_envs)
    return path, state, args


def train(args, given: frozenset[str] | None = None) -> Path:
    """Run the training ``args`` asks for (a ``TorchRLTraining``, or its schema-1 flags);
    returns the last checkpoint's path.

    The run folder follows rwalk-train's rule: its lock, and another run's checkpoints
    (of either trainer) refused unless --resume or --overwrite. --resume goes on from a
    torchrl checkpoint: models, optimizer, normalisations and the envs' curricula (terrain
    levels, command weights), with the run's own record
    (``given``: unused, kept for older callers; see ``resume_point``).

    Raises:
        FileNotFoundError, CheckpointError, ConfigError, ResumeConflict, RunSetupError:
            before anything is trained, naming the file, folder or flag (a folder in use
            or holding another run, a backend's missing extra).
        WorkerDied: a collector worker exited.
    """
    args = as_training(args)
    clock = time.perf_counter()  # the time budget counts from here, env building included
    require_backend(args.train.backend)  # before anything is written
    log_dir = Path(args.run.log_dir)
    resume = resume_point(args)
    if resume is not None:
        args = resume[2]
    run = args.run
    with run_lock(log_dir):  # one run writes to a folder at a time
        claimed = resume and (resume[0], resume[1]["iteration"])
        claim_log_dir(log_dir, claimed, Path(run.resume).is_dir() if run.resume else False,
                      run.overwrite)  # fmt: skip
        return _train(args, resume and resume[1], clock, resume and resume[0])


def _train(args: TorchRLTraining, state: dict[str, Any] | None, clock: float,
           resumed: Path | None = None) -> Path:  # fmt: skip
    run, setup, ppo = args.run, args, args.train
    log_dir = Path(run.log_dir)
    torch.manual_seed(run.seed)
    norms = None
    if state is not None:  # the resumed run's normalisation, not a new one
        norms = {key: (state[saved]["loc"], state[saved]["scale"])
                 for key, saved in (("policy", "obs_norm"), ("critic", "critic_norm"))}  # fmt: skip
    # With several collectors this env only gives the specs and the normalisation.
    saved = None if state is None else resumed_curricula(state.get("curricula"), ppo.collectors)
    env = make_env(setup, ppo.reward_scale, seed=run.seed, threads=run.threads, norms=norms)
    if ppo.backend != "process":
        print(f"[torchrl] note: TorchRL's {ppo.backend} collectors give no state_dict, so "
              f"checkpoints hold no curricula: a resumed run's terrain levels and command "
              f"weights start again", flush=True)  # fmt: skip
    note = write_record(log_dir / "config.json", args, TRAINER,
                        resumed and resumed.parent / "config.json")  # fmt: skip
    if note:
        print(f"[rwalk] note: {note}", flush=True)
    actor, critic = make_modules(ppo, env)
    first = 0
    if state is not None:
        try:
            actor.load_state_dict(state["actor"])
            critic.load_state_dict(state["critic"])
        except (RuntimeError, KeyError) as error:
            raise CheckpointError(
                f"checkpoint {str(run.resume)!r} does not fit this run's models: {quote(error)}"
            ) from None
        first = state["iteration"]
        print(f"[torchrl] resumed after iteration {first} from {run.resume}")
    norms = {t.in_keys[0]: t.state_dict() for t in env.transform if isinstance(t, ObservationNorm)}
    kept = {  # what every checkpoint holds beside the modules
        "obs_norm": norms["policy"],  # the actor's input normalisation
        "critic_norm": norms["critic"],
        "groups": {key: list(pieces) for key, pieces in env.base_env.groups.items()},
    }
    collector = make_collector(env, actor, setup, ppo, seed=run.seed, threads=run.threads,
                               iterations=run.max_iterations - first, curricula=saved)  # fmt: skip
    del env  # with several collectors the workers step their own envs
    try:
        frames = ppo.frames_per_batch(setup.num_envs)
        optimizer_state = state["optimizer"] if state is not None else None
        checkpoint = _learn(run, ppo, frames, collector, actor, critic, kept, clock, first,
                            optimizer_state)  # fmt: skip
    except BaseException:
        # Shut the workers down on an error too (they would keep this process alive), but
        # report the error itself: with a worker lost, shutting down may fail as well.
        with contextlib.suppress(Exception):
            collector.shutdown()
        raise
    collector.shutdown()
    return checkpoint


def _learn(
    run: RunSettings,
    ppo: TorchRLConfig,
    frames: int,
    collector: BaseCollector,
    actor: ProbabilisticActor,
    critic: ValueOperator,
    kept: dict[str, Any],
    clock: float,
    first: int = 0,
    optimizer_state: dict | None = None,
) -> Path:
    """PPO on the collector's batches of ``frames`` frames, from iteration ``first`` until
    ``run.max_iterations`` or the iteration that spends ``run.max_minutes``; returns the
    last checkpoint's path."""
    advantage = GAE(gamma=ppo.gamma, lmbda=ppo.lmbda, value_network=critic, average_gae=True)
    loss = ClipPPOLoss(
        actor,
        critic,
        clip_epsilon=ppo.clip_epsilon,
        entropy_coeff=ppo.entropy_coef,
        critic_coeff=1.0,
        loss_critic_type="smooth_l1",
    )
    optimizer = torch.optim.Adam(loss.parameters(), lr=ppo.learning_rate)
    if optimizer_state is not None:
        optimizer.load_state_dict(optimizer_state)
    buffer = ReplayBuffer(
        storage=LazyTensorStorage(frames),
        sampler=SamplerWithoutReplacement(),
        batch_size=frames // ppo.num_mini_batches,
    )
    budget = run.max_minutes * 60.0
    started = tick = time.perf_counter()
    checkpoint = Path(run.log_dir) / f"torchrl_{first}.pt"
    # with worker processes, their collecting is this process's share, not another's
    alone = run.share_cores and ppo.collectors == 1
    sharing = SharedCores(torch.get_num_threads()) if alone else None
    for it, batch in enumerate(collector, start=first):  # (N, T) or (collectors, N, T)
        collected = time.perf_counter()
        if sharing is not None:
            sharing.poll()
        with torch.no_grad():
            advantage(batch)
        buffer.extend(batch.reshape(-1))
        for _ in range(ppo.num_learning_epochs):
            for _ in range(ppo.num_mini_batches):
                parts = loss(buffer.sample())
                total = parts["loss_objective"] + parts["loss_critic"] + parts["loss_entropy"]
                optimizer.zero_grad()
                total.backward()
                nn.utils.clip_grad_norm_(loss.parameters(), 1.0)
                optimizer.step()
        check_workers(collector)  # a dead one would never acknowledge the weights
        collector.update_policy_weights_()  # to the workers, when there are any
        ended = batch["next", "done"].squeeze(-1)
        reward = batch["next", "reward"].mean().item() / ppo.reward_scale
        velocity = batch["next", "observation"][..., OBS_LINVEL.start].mean().item()
        now = time.perf_counter()
        out_of_time = now - clock >= budget
        eta = (now - started) / (it + 1 - first) * (run.max_iterations - it - 1)
        eta = min(eta, max(budget - (now - clock), 0.0))
        print(
            f"[torchrl] iteration {it + 1}/{run.max_iterations}  reward/step {reward:7.2f}  "
            f"v_x {velocity:+.4f} m/s  episodes ended {int(ended.sum())}  "
            f"{frames / (now - tick):,.0f} frames/s "
            f"(collecting {frames / (collected - tick):,.0f})  ETA {eta / 60:.1f} min",
            flush=True,
        )
        done = it + 1 == run.max_iterations or out_of_time
        if (it + 1) % run.save_interval == 0 or done:
            checkpoint = Path(run.log_dir) / f"torchrl_{it + 1}.pt"
            state = {
                "trainer": TRAINER,
                "iteration": it + 1,
                "actor": actor.state_dict(),
                "critic": critic.state_dict(),
                "optimizer": optimizer.state_dict(),
            }
            envs = curricula(collector)  # None where the backend gives no state
            if envs is not None:
                state["curricula"] = envs
            save_checkpoint(state | kept, checkpoint)
        if out_of_time and it + 1 < run.max_iterations:
            print(f"[torchrl] stopping: the {run.max_minutes:g}-minute budget is reached")
            break
        tick = time.perf_counter()  # saving is no part of an iteration's frames/s
    return checkpoint
