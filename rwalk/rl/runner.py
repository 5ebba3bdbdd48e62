"""``SafeRunner``: rsl-rl's ``OnPolicyRunner`` with checkpoints as data and the env's state.

rsl-rl's ``OnPolicyRunner.load`` unpickles with ``weights_only=False``, so a
crafted ``.pt`` file runs whatever it holds; ``SafeRunner`` reads every
checkpoint with ``torch.load(weights_only=True)`` first (``rwalk.rl.checkpoints``)
and writes it atomically. It saves the env's own state beside the policy through
one hook: an env with ``state_dict()`` / ``load_state_dict(state)`` (the rsl-rl
adapter's: the terrain curriculum's levels) has it written under ``"env_state"``
at each save and handed back at each load. Under torchrun it joins a gloo group
on CPU processes (``rwalk.rl.distributed``). rsl-rl's console report of each
iteration is silenced: its "Learning iteration" and ETA count only the ``learn()``
call, and rwalk-train reports the training's progress itself, once per chunk.
"""

from __future__ import annotations

import contextlib
import functools
import io

import torch
from rsl_rl.runners import DistillationRunner, OnPolicyRunner

from rwalk.rl import distributed
from rwalk.rl.checkpoints import (
    TRAINER,
    CheckpointError,
    check_rsl_rl,
    load_checkpoint,
    quote,
    save_checkpoint,
)


class SafeRunnerMixin:
    """What rwalk adds to an rsl-rl runner: checkpoints written atomically and read as
    data, the env's state beside the policy, and data-parallel training on CPU processes
    (gloo) under torchrun.

    Checkpoints carry ``"trainer": "rsl_rl"`` and ``"env_state"`` (rsl-rl's ``alg.load``
    ignores keys it does not know).
    """

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.logger.log = _without_console(self.logger.log)
        self.alg.update = _with_explained_variance(self.alg)
        symmetry = getattr(self.alg, "symmetry", None)
        if symmetry is not None and symmetry.use_data_augmentation and not symmetry.use_mirror_loss:
            symmetry.compute_loss = _mirror_loss_once_per_update(self.alg)

    def _configure_multi_gpu(self) -> None:
        """rsl-rl's multi-GPU setup for CPU processes: join a gloo group (torchrun's
        variables; ``rwalk.rl.distributed``) instead of NCCL on ``cuda:LOCAL_RANK``,
        and fill ``cfg["multi_gpu"]`` as rsl-rl's PPO reads it. A single process
        (WORLD_SIZE unset or 1) sets nothing up; a CUDA device keeps rsl-rl's own setup.
        """
        if str(self.device).startswith("cuda"):
            super()._configure_multi_gpu()
            return
        group = distributed.Group.from_env()
        self.gpu_world_size = group.world_size
        self.gpu_global_rank = group.rank
        self.gpu_local_rank = group.local_rank
        self.is_distributed = group.distributed
        distributed.join(group)  # a no-op if rwalk-train joined it already, with its timeout
        self.cfg["multi_gpu"] = distributed.multi_gpu_config(group)

    _saved: tuple[str, int] | None = None
    """(path, iteration) of the last save."""

    def save(self, path: str, infos: dict | None = None) -> None:
        """Write the algorithm's state, the iteration and the env's state to ``path``
        atomically.

        rsl-rl's ``learn()`` saves its last iteration twice when that iteration
        is a multiple of ``cfg["save_interval"]`` (in its loop and after it);
        the repeated save of the same iteration to the same path is skipped.
        """
        if self._saved == (str(path), self.current_learning_iteration):
            return
        saved = self.alg.save()
        saved["iter"] = self.current_learning_iteration
        saved["infos"] = infos
        saved["trainer"] = TRAINER
        state_dict = getattr(self.env, "state_dict", None)
        if state_dict is not None:
            saved["env_state"] = state_dict()
        save_checkpoint(saved, path)
        self._saved = (str(path), self.current_learning_iteration)
        self.logger.save_model(path, self.current_learning_iteration)

    def load(
        self,
        path: str,
        load_cfg: dict | None = None,
        strict: bool = True,
        map_location: str | None = None,
        data: bytes | None = None,
        env_state: bool = True,
        state: dict | None = None,
    ) -> dict | None:
        """Load the state ``path`` holds (``data``: its bytes, read by rank 0; ``state``: a
        checked state made of such files' parts, which ``path`` then only names); with
        ``env_state``, the env's too (the curriculum).

        Raises:
            FileNotFoundError: naming the file.
            CheckpointError: naming the file, if it is not an rsl-rl save, its models do not
                have the shapes this run's config builds, or its env state is not the env's.
        """
        loaded = state if state is not None else check_rsl_rl(load_checkpoint(path, data), path)
        try:
            resumed = self.alg.load(loaded, load_cfg, strict)
        except (RuntimeError, KeyError, ValueError, TypeError) as error:
            raise CheckpointError(
                f"checkpoint {str(path)!r} does not fit this run's models (another "
                f"--hidden-dims, task or observation pieces?): {quote(error)}"
            ) from None
        if resumed:
            self.current_learning_iteration = loaded["iter"]
        saved_env = loaded.get("env_state")
        if saved_env is None and "terrain_level" in loaded:  # saves from before the hook
            saved_env = {"terrain_level": loaded["terrain_level"]}
        load_state_dict = getattr(self.env, "load_state_dict", None)
        if env_state and load_state_dict is not None and saved_env:
            if not isinstance(saved_env, dict):
                raise CheckpointError(f"checkpoint {str(path)!r}: 'env_state' must be a dict")
            try:
                why = load_state_dict(saved_env)
            except ValueError as error:
                raise CheckpointError(f"checkpoint {str(path)!r}: env_state: {error}") from None
            if why:
                print(f"[rwalk] {path}: {why}")
        return None


class SafeRunner(SafeRunnerMixin, OnPolicyRunner):
    """rsl-rl's ``OnPolicyRunner`` (PPO) with ``SafeRunnerMixin``'s checkpoints and groups."""


class SafeDistillationRunner(SafeRunnerMixin, DistillationRunner):
    """rsl-rl's ``DistillationRunner`` with ``SafeRunnerMixin``'s checkpoints and groups:
    ``load(teacher_checkpoint)`` loads a teacher (its actor), a distillation checkpoint
    the student, the teacher and the optimizer."""


def _without_console(log):
    """rsl-rl's ``Logger.log`` (its writer's metrics and a console report) without the
    console report: a block per iteration headed "Learning iteration <it>/<end of this
    learn() call>" with an ETA to that end, beside the caller's own progress line."""

    @functools.wraps(log)
    def log_quietly(*args, **kwargs):
        with contextlib.redirect_stdout(io.StringIO()):
            return log(*args, **kwargs)

    return log_quietly


def _mirror_loss_once_per_update(alg):
    """rsl-rl's ``Symmetry.compute_loss`` where the mirror loss only feeds the log (data
    augmentation without ``use_mirror_loss``): rsl-rl runs the actor over every mirrored
    mini-batch with autograd, about a fifth of the default teacher's update, for a figure
    no gradient uses. This measures it on each update's first mini-batch, without
    autograd, and repeats it for the rest, so ``Loss/symmetry`` is that mini-batch's. The
    pass has no side effects (a deterministic output, no distribution update), so training
    is the same bits (tests/test_learning.py)."""
    compute = alg.symmetry.compute_loss
    per_update = alg.num_learning_epochs * alg.num_mini_batches
    calls, measured = 0, None

    def compute_loss(actor, batch, original_batch_size):
        nonlocal calls, measured
        if calls % per_update == 0:
            with torch.no_grad():
                measured = compute(actor, batch, original_batch_size)
        calls += 1
        return measured

    return compute_loss


def _with_explained_variance(alg):
    """``alg.update`` whose losses also hold ``explained_variance``: 1 - Var(returns -
    values) / Var(returns) of the rollout it learns from (how much of the returns the
    critic predicted; rsl-rl logs it as ``Loss/explained_variance``). A distillation's
    storage has no values: its update is unchanged."""
    update = alg.update

    @functools.wraps(update)
    def updated() -> dict:
        storage = getattr(alg, "storage", None)
        values, returns = getattr(storage, "values", None), getattr(storage, "returns", None)
        explained = None
        if values is not None and returns is not None:
            spread = returns.var()
            explained = float(1.0 - (returns - values).var() / spread) if spread > 0 else 0.0
        losses = update()
        if explained is not None:
            losses["explained_variance"] = explained
        return losses

    return updated
