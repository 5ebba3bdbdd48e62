"""A training with rsl-rl's PPO on the batched env: one process, or a torchrun group.

``train(args)`` runs what ``rwalk-train`` asks for (``args``: the flags of
``rwalk.rl.config.TrainArgs``). Rank 0 checks ``--resume``, takes the run
folder's lock and claims the folder (``rwalk.rl.checkpoints``); every rank builds
its own envs, with its own seeds and threads (``rank_args``), and steps them;
rsl-rl's data-parallel PPO averages the gradients over the gloo group
(``rwalk.rl.distributed``). ``learn()`` runs in chunks up to each checkpoint, and
after each chunk rank 0's clock decides for every rank whether the time budget
is spent. Rank 0 alone writes config.json, TensorBoard, checkpoints and exports.
"""

from __future__ import annotations

import contextlib
import dataclasses
import importlib.metadata
import json
import os
import time
from pathlib import Path
from typing import Any, NamedTuple

import mujoco
import numpy as np
import torch

from rwalk.cli import flag, show_flag
from rwalk.envs.torchrl_env import BatchedEnv
from rwalk.export import export_policy
from rwalk.progress import Progress
from rwalk.rl import distributed
from rwalk.rl.checkpoints import (
    TRAINER,
    CheckpointError,
    RunSetupError,
    atomic_write_text,
    check_rsl_rl,
    claim_log_dir,
    load_checkpoint,
    newest_checkpoint,
    run_lock,
)
from rwalk.rl.config import (
    ConfigError,
    ResumeConflict,
    load_saved_args,
    mirrored,
    observation_groups,
    restore_run,
)
from rwalk.rl.rsl_rl_env import RslRlVecEnv
from rwalk.rl.runner import SafeDistillationRunner, SafeRunner
from rwalk.starts import SettleError

PER_RANK_FLAGS = ("threads",)
"""Flags the ranks of one training may set differently: a machine's own resources."""
SETUP_ERRORS = (CheckpointError, ConfigError, FileNotFoundError, ResumeConflict, RunSetupError,
                SettleError, MemoryError)  # fmt: skip
"""Errors of a run that cannot start as asked (a one-line message each): rank 0's setup
errors reach every rank (same message)."""


class Teacher(NamedTuple):
    """The frozen teacher of a distillation (--distill)."""

    path: Path
    args: Any
    """Its run's flags (``TrainArgs``)."""


def make_env(args, teacher: Teacher | None = None) -> RslRlVecEnv:
    """The training's envs for rsl-rl, with the groups of the one rule
    (``rwalk.rl.config.observation_groups``): the policy's and the critic's, or for a
    distillation the student's (``policy``) and the teacher's."""
    vec = BatchedEnv(args.num_envs, args.env.config(args.threads), seed=args.seed, task=args.task)
    vec.core.settle_progress = Progress("settling starts", "physics steps")
    groups = observation_groups(vec.core.task, args.env, args.train)
    if teacher is not None:  # the teacher acts on its own policy group
        teacher_obs = observation_groups(vec.core.task, teacher.args.env, teacher.args.train)
        env = RslRlVecEnv(
            vec,
            policy_obs=groups["policy"],
            critic_obs=(),
            reward_scale=args.reward_scale,
            teacher_obs=teacher_obs["policy"],
        )
    else:
        env = RslRlVecEnv(
            vec,
            policy_obs=groups["policy"],
            critic_obs=groups["critic"],
            reward_scale=args.reward_scale,
        )
    if mirrored(args):  # every piece of every group mirrors (ValueError naming one that does not)
        for group in env.groups:
            env.mirror(group)
        env.action_mirror()
    return env


def rsl_rl_config(args, teacher: Teacher | None = None) -> dict[str, Any]:
    """rsl-rl-lib 5.x's training config of ``args`` (a fresh dict): PPO, or a distillation
    of ``teacher``, with its writer (--logger)."""
    config = args.train.to_rsl_rl(args.save_interval, teacher and teacher.args.train)
    if args.logger == "wandb":
        config["logger"] = {
            "class_name": "rwalk.rl.wandb_writer:WandbWriter",
            "project_name": args.wandb_project, "run_name": args.run_name,
        }  # fmt: skip
    return config


def teacher_of(args) -> Teacher | None:
    """The teacher --distill names, checked against this run: an rsl-rl PPO checkpoint of
    a run trained with --teacher, of this task and world.

    Raises:
        FileNotFoundError, CheckpointError, ConfigError: naming the file.
        RunSetupError: naming the flag and both values, for a checkpoint that is no teacher
            of this run (a student, no --teacher, another task, world or commands).
    """
    if not args.distill:
        return None
    if Path(args.distill).is_dir():  # its newest checkpoint that loads
        path, state = newest_checkpoint(args.distill)
    else:
        path = Path(args.distill)
        state = check_rsl_rl(load_checkpoint(path), path)
    if "actor_state_dict" not in state:
        raise RunSetupError(f"--distill {path}: a distilled student, not a teacher trained "
                            "with --teacher")  # fmt: skip
    config = path.parent / "config.json"
    if not config.is_file():
        raise FileNotFoundError(f"--distill {path}: its run's config.json is not beside it")
    teacher = load_saved_args(config)
    if not teacher.teacher:
        raise RunSetupError(
            f"--distill {path}: its run trained without --teacher, so its actor reads no "
            "privileged pieces; train a teacher with rwalk-train --teacher"
        )
    for name in ("task", "robust", "command_range"):
        if getattr(teacher, name) != getattr(args, name):
            raise RunSetupError(
                f"--distill {path}: its teacher trained with "
                f"{show_flag(name, getattr(teacher, name))}, this student with "
                f"{show_flag(name, getattr(args, name))}: a teacher teaches its own task and world"
            )
    return Teacher(path, teacher)


def start_as_base_gait(runner) -> None:
    """Zero the actor's output layer: the untrained policy's mean residual is 0, so
    training starts from the base gait (random output weights made the robots
    stumble: white-noise residuals of a few mm at 50 Hz stop the gait)."""
    last = [m for m in runner.alg.get_policy().mlp.modules() if isinstance(m, torch.nn.Linear)][-1]
    with torch.no_grad():
        last.weight.zero_()
        last.bias.zero_()


def resume_point(args, given: frozenset[str] | None = None):
    """The checkpoint --resume names (a file, or a folder's newest that loads), its
    iteration, and the flags to train on: ``args`` with the run's own task, world and
    models (``restore_run``; from its config.json where there is one).

    Returns:
        (path, iteration, args), or None without --resume.

    Raises:
        FileNotFoundError, CheckpointError, ConfigError: naming the file or folder.
        RunSetupError: if the checkpoint's iteration leaves nothing to train, or a flag
            contradicts the run's.
    """
    if not args.resume:
        return None
    if Path(args.resume).is_dir():
        path, state = newest_checkpoint(args.resume)
    else:
        path = Path(args.resume)
        state = check_rsl_rl(load_checkpoint(path), path)
    iteration = state["iter"]
    if iteration + 1 >= args.max_iterations:
        raise RunSetupError(
            f"--resume {path} holds iteration {iteration}, so --max-iterations "
            f"{args.max_iterations} leaves nothing to train (iterations count from 0); "
            f"pass --max-iterations {iteration + 2} or more"
        )
    saved = path.parent / "config.json"
    if saved.is_file():
        args = restore_run(args, load_saved_args(saved), given, path, saved)
    return path, iteration, args


def run_settings(args) -> dict[str, Any]:
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


def rank_args(args, group: distributed.Group):
    """The flags of this rank's envs. One process: ``args``. Rank r of a group: seed
    ``args.seed + r * (num_envs + pool)``, so that its envs and settled-start pool entries
    (keyed seed + i, then seed + num_envs + j; ``rwalk.starts``) share no key with another
    rank's; --threads 0 becomes the machine's cores divided among its ranks."""
    if not group.distributed:
        return args
    stride = args.num_envs + args.env.config().settle_pool
    threads = args.threads or distributed.default_threads(group)
    return dataclasses.replace(args, seed=args.seed + group.rank * stride, threads=threads)


def train(args, given: frozenset[str] | None = None) -> Path:
    """Run the training; returns the last checkpoint's path.

    Under torchrun (WORLD_SIZE > 1) every rank runs this and joins the gloo group
    first, and ends when its launcher dies (``distributed.exit_with_launcher``); a
    single process sets nothing up.

    Args:
        given: the flags the command line set itself; with --resume the others come
            from the run's config.json (``restore_run``; None: every flag is as given,
            and one that contradicts the run's is refused).

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
    if group.distributed:
        distributed.exit_with_launcher()
    distributed.join(group, args.dist_timeout)
    try:
        distributed.check_same_settings(group, run_settings(args))
        checkpoint, args = _train(args, given, group, clock)
        if args.student_iterations:
            checkpoint, _ = _train(student_args(args), None, group, time.perf_counter())
        return checkpoint
    finally:
        distributed.leave()


def student_args(teacher):
    """The flags of the student stage of ``teacher`` (a run with --student-iterations):
    distil LOG_DIR's teacher into a --student-actor model in LOG_DIR/student, for
    --student-iterations iterations, with the teacher's world, PPO settings and
    --overwrite."""
    return dataclasses.replace(
        teacher, teacher=False, distill=teacher.log_dir, actor=teacher.student_actor,
        student_iterations=0, symmetry=False, resume="", max_iterations=teacher.student_iterations,
        log_dir=str(Path(teacher.log_dir) / "student"),
        run_name=f"{teacher.run_name or Path(teacher.log_dir).name}-student",
    )  # fmt: skip


class Setup(NamedTuple):
    """What a run starts from, as rank 0 found it."""

    args: Any
    """The flags to train on (the resumed run's own, for --resume)."""
    resume: tuple[Path, int] | None
    """The checkpoint to go on from and its iteration."""
    resume_data: bytes | None
    """Its bytes, read by rank 0 (None in a single process: it reads the file itself)."""
    teacher: Teacher | None
    """The teacher of a distillation."""
    teacher_data: bytes | None
    """Its checkpoint's bytes, read by rank 0 (None in a single process)."""


def _claim_run(args, given, group: distributed.Group, stack: contextlib.ExitStack) -> Setup:
    """Rank 0 checks --resume and --distill, takes the run folder's lock (held until
    ``stack`` closes) and claims the folder; every rank gets rank 0's setup, or its error."""
    resume, teacher, failure = None, None, None
    if group.main:
        try:
            resume = resume_point(args, given)
            if resume is not None:
                args = resume[2]
            teacher = teacher_of(args)
            if args.logger == "wandb":
                from rwalk.rl import wandb_writer

                if not wandb_writer.available():
                    raise RunSetupError(wandb_writer.MISSING)
            log_dir = Path(args.log_dir)
            stack.enter_context(run_lock(log_dir))
            claim_log_dir(log_dir, resume and resume[:2],
                          Path(args.resume).is_dir() if args.resume else False,
                          args.overwrite)  # fmt: skip
        except Exception as error:  # the other ranks wait to hear of it
            failure = error
    distributed.raise_if_failed(group, failure, SETUP_ERRORS)
    if not group.distributed:
        return Setup(args, resume and resume[:2], None, teacher, None)
    sent = {
        "args": dataclasses.asdict(args),
        "resume": resume and [str(resume[0]), resume[1]],
        "teacher": teacher and [str(teacher.path), dataclasses.asdict(teacher.args)],
    }
    shared = distributed.broadcast_json(group, sent if group.main else None)
    files = []
    for found, key in ((resume, "resume"), (teacher, "teacher")):
        data = found[0].read_bytes() if group.main and found else None
        files.append(distributed.broadcast_bytes(group, data) if shared[key] else None)
    return Setup(
        type(args).from_saved(shared["args"]),
        shared["resume"] and (Path(shared["resume"][0]), int(shared["resume"][1])),
        files[0],
        shared["teacher"] and Teacher(Path(shared["teacher"][0]),
                                      type(args).from_saved(shared["teacher"][1])),
        files[1],
    )  # fmt: skip


def _train(args, given, group: distributed.Group, clock: float) -> tuple[Path, Any]:
    """One run (a stage): returns its last checkpoint and the flags it trained on."""
    say = print if group.main else lambda *_, **__: None  # rank 0 speaks for the group
    log_dir = Path(args.log_dir)
    with contextlib.ExitStack() as stack:  # rank 0 holds the lock until the run ends
        setup = _claim_run(args, given, group, stack)
        own = {name: getattr(args, name) for name in PER_RANK_FLAGS}  # not rank 0's
        args = dataclasses.replace(setup.args, **own)
        resume, teacher = setup.resume, setup.teacher
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
        env = make_env(mine, teacher)
        say(f"  ready in {time.perf_counter() - clock:.1f} s", flush=True)
        runner_class = SafeDistillationRunner if teacher else SafeRunner
        writes = str(log_dir) if group.main else None
        runner = runner_class(env, rsl_rl_config(args, teacher), log_dir=writes, device="cpu")
        hashes = os.environ.get(distributed.PARAMETER_HASHES_ENV)
        if hashes:
            distributed.record_parameter_hashes(runner, hashes, group)
        if resume is None:
            start_as_base_gait(runner)  # learn() then broadcasts rank 0's parameters
            if teacher is not None:  # its actor only: the student's curriculum is its own
                runner.load(str(teacher.path), data=setup.teacher_data, env_state=False)
                say(f"distilling the teacher {teacher.path}")
        else:  # every rank loads rank 0's file
            runner.load(str(resume[0]), data=setup.resume_data)
            if env.core.terrain_map is not None:
                env.core.reset()  # every env restarts on its level of the resumed curriculum
            runner.current_learning_iteration += 1  # continue after the saved iteration
            say(f"resumed from {resume[0]}: next iteration {runner.current_learning_iteration}")
        if group.main:
            config = {"trainer": TRAINER, "args": dataclasses.asdict(args),
                      "env": dataclasses.asdict(env.env.config)}  # fmt: skip
            atomic_write_text(log_dir / "config.json", json.dumps(config, indent=2))
        checkpoint = _learn(args, runner, group, clock)
        if args.logger == "wandb" and group.main:
            from rwalk.rl.wandb_writer import WandbWriter

            WandbWriter.finish()  # the stage's W&B run ends with it
        if args.export and group.main:
            jit_path, onnx_path = export_policy(runner, log_dir / "exported")
            print(f"[rwalk] exported {jit_path} and {onnx_path} (layout: policy.json)")
    return checkpoint, args


def _learn(args, runner: SafeRunner, group: distributed.Group, clock: float) -> Path:
    """``runner.learn`` in chunks up to each checkpoint, until --max-iterations or the
    time budget; returns the last checkpoint's path."""
    say = print if group.main else lambda *_, **__: None
    first = runner.current_learning_iteration
    budget = args.max_minutes * 60.0
    learning_since = time.perf_counter()  # per-iteration time excludes building the envs
    checkpoint = Path(args.log_dir) / f"model_{first}.pt"
    while runner.current_learning_iteration < args.max_iterations:
        it = runner.current_learning_iteration
        # One learn() call up to the next checkpoint: rsl-rl saves the multiples of
        # save_interval in its loop and the call's last iteration after it.
        last = min(-(-it // args.save_interval) * args.save_interval, args.max_iterations - 1)
        runner.learn(num_learning_iterations=last + 1 - it, init_at_random_ep_len=it == first)
        if runner.logger.writer is not None:  # rank 0's; learn() opens one each call
            runner.logger.writer.close()
        checkpoint = Path(args.log_dir) / f"model_{last}.pt"
        runner.current_learning_iteration = last + 1  # learn() leaves it at its last one
        now = time.perf_counter()
        elapsed = now - clock
        per_iteration = (now - learning_since) / (last + 1 - first)
        left = args.max_iterations - (last + 1)
        eta = min(left * per_iteration, max(budget - elapsed, 0.0))
        say(
            f"[rwalk] iteration {last + 1}/{args.max_iterations}, "
            f"{elapsed / 60:.1f} min elapsed, ETA {eta / 60:.1f} min, checkpoint {checkpoint}",
            flush=True,
        )
        # Rank 0's clock decides for every rank: all stop after the same iteration.
        over = elapsed + per_iteration * min(args.save_interval, left) > budget
        if distributed.agree(group, over):
            say(f"[rwalk] stopping: the {args.max_minutes:g}-minute budget is reached")
            break
    return checkpoint
