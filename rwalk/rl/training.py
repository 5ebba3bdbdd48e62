"""A training with rsl-rl's PPO on the batched env: one process, or a torchrun group.

``train(args)`` runs what ``rwalk-train`` asks for (``args``: a
``rwalk.rl.config.Training``; schema-1 flags, ``TrainArgs``, are migrated). Rank 0
checks ``--resume``, takes the run
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
import functools
import importlib.metadata
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, NamedTuple

import mujoco
import numpy as np
import torch

from rwalk.envs.torchrl_env import BatchedEnv
from rwalk.export import export_policy
from rwalk.progress import Progress
from rwalk.rl import distributed
from rwalk.rl.checkpoints import (
    TRAINER,
    CheckpointError,
    RunSetupError,
    check_rsl_rl,
    claim_log_dir,
    load_checkpoint,
    newest_checkpoint,
    run_lock,
)
from rwalk.rl.config import (
    LATE_VALUES,
    ResumeConflict,
    RunConfig,
    TrainConfig,
    Training,
    finetune_training,
    flag_of,
    late_reward,
    leaves,
    mirrored,
    resume_conflict,
    student_training,
)
from rwalk.rl.legacy import as_training
from rwalk.rl.ppo import SMOOTHING_OBS
from rwalk.rl.record import ConfigError, decode_training, read_record, record_of, write_record
from rwalk.rl.rsl_rl_env import RslRlVecEnv
from rwalk.rl.runner import SafeDistillationRunner, SafeRunner
from rwalk.starts import SettleError
from rwalk.threads import SharedCores
from rwalk.validation import flag, show_flag

PER_RANK_FLAGS = ("threads",)
"""Flags the ranks of one training may set differently: a machine's own resources."""
SETUP_ERRORS = (CheckpointError, ConfigError, FileNotFoundError, ResumeConflict, RunSetupError,
                SettleError, MemoryError)  # fmt: skip
"""Errors of a run that cannot start as asked (a one-line message each): rank 0's setup
errors reach every rank (same message)."""


class Teacher(NamedTuple):
    """The frozen teacher of a distillation (--distill)."""

    path: Path
    args: Training
    """Its run's record."""


def make_env(args, teacher: Teacher | None = None) -> RslRlVecEnv:
    """The training's envs for rsl-rl (``args``: a ``Training``, or schema-1 flags), with
    its record's groups: the policy's and the critic's, or for a distillation the
    student's (``policy``) and the teacher's own policy group."""
    args = as_training(args).resolved()
    vec = BatchedEnv(args.num_envs, args.env_config(), seed=args.run.seed, task=args.task)
    vec.core.settle_progress = Progress("settling starts", "physics steps")
    train = args.train
    if teacher is not None:  # the teacher acts on its own policy group
        env = RslRlVecEnv(vec, policy_obs=train.policy_obs, critic_obs=(),
                          reward_scale=train.reward_scale,
                          teacher_obs=teacher.args.train.policy_obs)  # fmt: skip
    else:
        env = RslRlVecEnv(vec, policy_obs=train.policy_obs, critic_obs=train.critic_obs,
                          reward_scale=train.reward_scale,
                          smoothing_obs=SMOOTHING_OBS if train.lag_smoothness else ())  # fmt: skip
    if mirrored(train):  # every piece of every group mirrors (ValueError naming one that does not)
        for group in env.groups:
            env.mirror(group)
        env.action_mirror()
    return env


def rsl_rl_config(args, teacher: Teacher | None = None) -> dict[str, Any]:
    """rsl-rl-lib 5.x's training config of ``args`` (a ``Training``, or schema-1 flags; a
    fresh dict): PPO, or a distillation of ``teacher``, with its writer (--logger)."""
    args = as_training(args)
    config = args.train.to_rsl_rl(args.run.save_interval, teacher and teacher.args.train)
    if args.run.logger == "wandb":
        config["logger"] = {
            "class_name": "rwalk.rl.wandb_writer:WandbWriter",
            "project_name": args.run.wandb_project, "run_name": args.run.run_name,
        }  # fmt: skip
    return config


def _run_checkpoint(flag: str, value: str) -> tuple[Path, dict[str, Any], Training]:
    """The checkpoint a flag names (a file, or a folder's newest that loads), its state,
    and its run's record (the config.json beside it).

    Raises:
        FileNotFoundError, CheckpointError, ConfigError: naming the flag and the file.
    """
    try:
        if Path(value).is_dir():  # its newest checkpoint that loads
            path, state = newest_checkpoint(value)
        else:
            path = Path(value)
            state = check_rsl_rl(load_checkpoint(path), path)
        config = path.parent / "config.json"
        if not config.is_file():
            raise FileNotFoundError(f"its run's config.json is not beside {str(path)!r}")
        return path, state, read_record(config)
    except (FileNotFoundError, CheckpointError, ConfigError) as error:
        raise type(error)(f"{flag} {value}: {error}") from None


def teacher_of(args) -> Teacher | None:
    """The teacher --distill names, checked against this run: an rsl-rl PPO checkpoint of
    a run trained with --teacher, of this task and world.

    Raises:
        FileNotFoundError, CheckpointError, ConfigError: naming the file.
        RunSetupError: naming the flag and both values, for a checkpoint that is no teacher
            of this run (a student, no --teacher, another task, world or commands).
    """
    distill = args.train.distill
    if not distill:
        return None
    path, state, teacher = _run_checkpoint("--distill", distill)
    if "actor_state_dict" not in state:
        raise RunSetupError(f"--distill {path}: a distilled student, not a teacher trained "
                            "with --teacher")  # fmt: skip
    if path.parent.resolve() == Path(args.run.log_dir).resolve():
        raise RunSetupError(f"--distill {path}: the teacher's run is --log-dir "
                            f"{args.run.log_dir}; the student would write over it: choose "
                            "another --log-dir")  # fmt: skip
    if not teacher.train.teacher:
        raise RunSetupError(
            f"--distill {path}: its run trained without --teacher, so its actor reads no "
            "privileged pieces; train a teacher with rwalk-train --teacher"
        )
    sides = {"--task": lambda t: t.task, "--robust": lambda t: t.env.varies,
             "--command-range": lambda t: t.env.command_range}  # fmt: skip
    for name, side in sides.items():
        if side(teacher) != side(args):
            raise RunSetupError(
                f"--distill {path}: its teacher trained with {shown(name, side(teacher))}, this "
                f"student with {shown(name, side(args))}: a teacher teaches its own task and world"
            )
    return Teacher(path, teacher)


#: What a --warm-start checkpoint's run must share with the run it starts: the task, the
#: pieces its actor reads and the actor's model; and what --warm-start-critic's (else the
#: --warm-start checkpoint's own) must share: the task, the pieces its critic reads and
#: the critic's model (a recurrent layer's size only for a recurrent model).
WARM_START_ACTOR = ("--task", "--policy-obs", "--actor", "--hidden-dims", "--rnn-hidden-dim")
WARM_START_CRITIC = ("--task", "--critic-obs", "--critic", "--hidden-dims", "--rnn-hidden-dim")


class WarmStart(NamedTuple):
    """The checkpoints a new run starts its models from (--warm-start)."""

    actor: Path
    """Its actor's (a PPO actor's, or a distilled student's), and the curriculum's with
    --warm-start-levels."""
    critic: Path | None
    """Its critic's (--warm-start-critic; None: ``actor``'s own)."""


def warm_start_of(args: Training) -> WarmStart | None:
    """The checkpoints --warm-start and --warm-start-critic name, checked against this run:
    rsl-rl saves of runs of this task whose actor (a PPO actor, or a distilled student) and
    critic (PPO's) read the same pieces with the same models (``WARM_START_ACTOR``,
    ``WARM_START_CRITIC``).

    Raises:
        FileNotFoundError, CheckpointError, ConfigError: naming the flag and the file.
        RunSetupError: naming the flag and both values, for a checkpoint that does not fit.
    """
    train = args.train
    if not train.warm_start:
        return None
    mine = args.resolved()
    path, state, theirs = _run_checkpoint("--warm-start", train.warm_start)
    _fits("--warm-start", path, theirs, mine, WARM_START_ACTOR)
    if not train.warm_start_critic:
        if "critic_state_dict" not in state:
            raise RunSetupError(f"--warm-start {path}: a distilled student has no critic (nor a "
                                "trained action std): name its teacher's checkpoint with "
                                "--warm-start-critic")  # fmt: skip
        _fits("--warm-start", path, theirs, mine, WARM_START_CRITIC)
        return WarmStart(path, None)
    critic, saved, run = _run_checkpoint("--warm-start-critic", train.warm_start_critic)
    if "critic_state_dict" not in saved:
        raise RunSetupError(f"--warm-start-critic {critic}: a distilled student, not a policy "
                            "trained with PPO (it has no critic)")  # fmt: skip
    _fits("--warm-start-critic", critic, run, mine, WARM_START_CRITIC)
    return WarmStart(path, critic)


def _fits(option: str, path: Path, theirs: Training, mine: Training, names: tuple[str, ...]
          ) -> None:  # fmt: skip
    """Refuse a checkpoint whose run (``theirs``) differs from this one on a flag of
    ``names`` (RunSetupError naming ``option``, the flag and both values)."""

    def side(training: Training, name: str) -> Any:
        field = name[2:].replace("-", "_")
        if field == "task":
            return training.task
        return training.train.critic_kind if field == "critic" else getattr(training.train, field)

    recurrent = mine.train.critic_kind if "--critic" in names else mine.train.actor
    for name in names:
        if name == "--rnn-hidden-dim" and recurrent == "mlp":
            continue
        if side(theirs, name) != side(mine, name):
            raise RunSetupError(
                f"{option} {path}: its run trained with {shown(name, side(theirs, name))}, "
                f"this run with {shown(name, side(mine, name))}: a warm start needs the same "
                "task, observation pieces and models"
            )


def _warm_start(runner, setup: Setup, levels: bool) -> None:
    """Load the warm start's actor and critic (and with ``levels`` its curriculum) into
    ``runner``: a distilled student's action std, never trained, from the critic's run."""
    warm = setup.warm_start
    loaded = check_rsl_rl(load_checkpoint(warm.actor, setup.warm_start_data), warm.actor)
    actor = loaded.get("actor_state_dict") or loaded["student_state_dict"]
    critic = loaded
    if warm.critic is not None:
        critic = check_rsl_rl(load_checkpoint(warm.critic, setup.warm_start_critic_data),
                              warm.critic)  # fmt: skip
        if "actor_state_dict" not in loaded:
            std = {k: v for k, v in critic["actor_state_dict"].items()
                   if k.startswith("distribution.")}  # fmt: skip
            actor = actor | std
    state = {"actor_state_dict": actor, "critic_state_dict": critic["critic_state_dict"],
             "env_state": loaded.get("env_state")}  # fmt: skip
    runner.load(str(warm.actor), {"actor": True, "critic": True}, state=state, env_state=levels)
    if levels and runner.env.core.terrain_map is not None:
        runner.env.core.reset()  # every env restarts on the warm start's level


def shown(option: str, value: Any) -> str:
    """A flag and its value as typed (``--no-robust``, ``--task adaptive_gait``)."""
    return show_flag(option[2:], value)


def start_as_base_gait(runner) -> None:
    """Zero the actor's output layer: the untrained policy's mean residual is 0, so
    training starts from the base gait (random output weights made the robots
    stumble: white-noise residuals of a few mm at 50 Hz stop the gait)."""
    last = [m for m in runner.alg.get_policy().mlp.modules() if isinstance(m, torch.nn.Linear)][-1]
    with torch.no_grad():
        last.weight.zero_()
        last.bias.zero_()


def resume_point(args: Training):
    """The checkpoint --resume names (a file, or a folder's newest that loads), its
    iteration, and the training to go on with: the run's own record (from its
    config.json where there is one) with this command's run settings and --num-envs.

    Returns:
        (path, iteration, training), or None without --resume.

    Raises:
        FileNotFoundError, CheckpointError, ConfigError: naming the file or folder.
        RunSetupError: if the checkpoint's iteration leaves nothing to train.
        ResumeConflict: naming the flag and both values, for a field of ``args`` (outside
            the run's settings and --num-envs) that differs from the run's.
    """
    run = args.run
    if not run.resume:
        return None
    if Path(run.resume).is_dir():
        path, state = newest_checkpoint(run.resume)
    else:
        path = Path(run.resume)
        state = check_rsl_rl(load_checkpoint(path), path)
    iteration = state["iter"]
    if iteration + 1 >= run.max_iterations:
        raise RunSetupError(
            f"--resume {path} holds iteration {iteration}, so --max-iterations "
            f"{run.max_iterations} leaves nothing to train (iterations count from 0); "
            f"pass --max-iterations {iteration + 2} or more"
        )
    saved = path.parent / "config.json"
    if saved.is_file():
        record = read_record(saved)
        resume_conflict(args, record, path, saved)
        args = dataclasses.replace(record, run=run, num_envs=args.num_envs)
    return path, iteration, args


def run_settings(args: Training) -> dict[str, Any]:
    """What every rank of a training must share: its record (but ``PER_RANK_FLAGS``) and
    the versions of the libraries that compute (JSON-able; keys are the fields' dotted
    paths and package names)."""
    flags = {flag_of(path): value for path, value in leaves(args).items()
             if path not in (f"run.{name}" for name in PER_RANK_FLAGS)}  # fmt: skip
    versions = {
        "torch": torch.__version__,
        "rsl-rl-lib": importlib.metadata.version("rsl-rl-lib"),
        "mujoco": mujoco.__version__,
        "numpy": np.__version__,
    }
    return flags | versions


def rank_args(args: Training, group: distributed.Group) -> Training:
    """The training of this rank's envs. One process: ``args``. Rank r of a group: seed
    ``seed + r * (num_envs + pool)``, so that its envs and settled-start pool entries
    (keyed seed + i, then seed + num_envs + j; ``rwalk.starts``) share no key with another
    rank's; --threads 0 becomes the machine's cores divided among its ranks."""
    if not group.distributed:
        return args
    stride = args.num_envs + args.env.settle_pool
    run = args.run
    threads = run.threads or distributed.default_threads(group)
    mine = dataclasses.replace(run, seed=run.seed + group.rank * stride, threads=threads)
    return dataclasses.replace(args, run=mine)


def train(args, given: frozenset[str] | None = None) -> Path:
    """Run the training (``args``: a ``Training``, or schema-1 flags); returns the last
    checkpoint's path.

    Under torchrun (WORLD_SIZE > 1) every rank runs this and joins the gloo group
    first, and ends when its launcher dies (``distributed.exit_with_launcher``); a
    single process sets nothing up. With --resume, a field that differs from the run's
    own record is refused (``rwalk.rl.config.resume_conflict``; ``rwalk-train`` parses
    its flags from that record, so only the flags typed can differ).

    Args:
        given: unused (older callers passed the flags the command line set).

    Raises:
        FileNotFoundError, CheckpointError, RunSetupError: before anything is
            trained, naming the file, folder or flags at fault (under torchrun,
            rank 0's, on every rank).
        distributed.GroupError: ranks started with different flags or torchrun
            variables that make no group (naming them).
        RuntimeError: under torchrun, another rank died or hung past --dist-timeout
            (``distributed.is_group_failure``).
    """
    args = as_training(args).resolved()
    clock = time.perf_counter()  # the wall-time budget counts from here, env building included
    group = distributed.Group.from_env()
    if group.distributed:
        distributed.exit_with_launcher()
    distributed.join(group, args.run.dist_timeout)
    try:
        distributed.check_same_settings(group, run_settings(args))
        checkpoint, args, teacher = _train(args, group, clock)
        if args.train.student_iterations:
            checkpoint, args, teacher = _train(student_training(args), group, time.perf_counter())
        if args.train.finetune_iterations:  # a student's, distilled just now or resumed
            stage = finetune_training(args, checkpoint, teacher.path, teacher.args)
            checkpoint, *_ = _train(stage, group, time.perf_counter())
        return checkpoint
    finally:
        distributed.leave()


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
    warm_start: WarmStart | None = None
    """The checkpoints whose actor and critic a new run starts from (--warm-start)."""
    warm_start_data: bytes | None = None
    """The actor's checkpoint's bytes, read by rank 0 (None in a single process)."""
    warm_start_critic_data: bytes | None = None
    """The critic's (--warm-start-critic), likewise."""


def _claim_run(args: Training, group: distributed.Group, stack: contextlib.ExitStack) -> Setup:
    """Rank 0 checks --resume, --distill and --warm-start, takes the run folder's lock (held
    until ``stack`` closes) and claims the folder; every rank gets rank 0's setup, or its
    error."""
    resume, teacher, warm, failure = None, None, None, None
    if group.main:
        try:
            resume = resume_point(args)
            if resume is not None:
                args = resume[2]
            teacher = teacher_of(args)
            warm = None if resume else warm_start_of(args)  # resuming, the run's own state
            run = args.run
            if run.logger == "wandb":
                from rwalk.rl import wandb_writer

                if not wandb_writer.available():
                    raise RunSetupError(wandb_writer.MISSING)
            log_dir = Path(run.log_dir)
            stack.enter_context(run_lock(log_dir))
            claim_log_dir(log_dir, resume and resume[:2],
                          Path(run.resume).is_dir() if run.resume else False,
                          run.overwrite)  # fmt: skip
        except Exception as error:  # the other ranks wait to hear of it
            failure = error
    distributed.raise_if_failed(group, failure, SETUP_ERRORS)
    if not group.distributed:
        return Setup(args, resume and resume[:2], None, teacher, None, warm)
    sent = {
        "args": record_of(args),
        "resume": resume and [str(resume[0]), resume[1]],
        "teacher": teacher and [str(teacher.path), record_of(teacher.args)],
        "warm_start": warm and str(warm.actor),
        "warm_start_critic": warm and warm.critic and str(warm.critic),
    }
    shared = distributed.broadcast_json(group, sent if group.main else None)
    files = []
    for found, key in ((resume and resume[0], "resume"), (teacher and teacher.path, "teacher"),
                       (warm and warm.actor, "warm_start"),
                       (warm and warm.critic, "warm_start_critic")):  # fmt: skip
        data = found.read_bytes() if group.main and found else None
        files.append(distributed.broadcast_bytes(group, data) if shared[key] else None)
    critic = shared["warm_start_critic"]
    return Setup(
        _received(shared["args"]),
        shared["resume"] and (Path(shared["resume"][0]), int(shared["resume"][1])),
        files[0],
        shared["teacher"] and Teacher(Path(shared["teacher"][0]),
                                      _received(shared["teacher"][1])),
        files[1],
        shared["warm_start"] and WarmStart(Path(shared["warm_start"]), critic and Path(critic)),
        files[2],
        files[3],
    )  # fmt: skip


def _received(record: dict) -> Training:
    """A training from rank 0's record, broadcast as JSON."""
    return decode_training(Training, {k: v for k, v in record.items()
                                      if k not in ("schema", "trainer")})  # fmt: skip


def _train(args: Training, group: distributed.Group, clock: float
           ) -> tuple[Path, Training, Teacher | None]:  # fmt: skip
    """One run (a stage): returns its last checkpoint, the training it ran and its teacher
    (a distillation's)."""
    say = print if group.main else lambda *_, **__: None  # rank 0 speaks for the group
    with contextlib.ExitStack() as stack:  # rank 0 holds the lock until the run ends
        setup = _claim_run(args, group, stack)
        own = {name: getattr(args.run, name) for name in PER_RANK_FLAGS}  # not rank 0's
        args = dataclasses.replace(setup.args, run=dataclasses.replace(setup.args.run, **own))
        log_dir = Path(args.run.log_dir)
        resume, teacher = setup.resume, setup.teacher
        mine = rank_args(args, group)
        torch.manual_seed(args.run.seed + group.rank)
        if mine.run.threads:  # the process's share of the cores, for learning too
            torch.set_num_threads(mine.run.threads)
        if group.distributed:
            print(
                f"[rwalk] rank {group.rank} of {group.world_size} (pid {os.getpid()}): "
                f"{mine.num_envs} envs seeded from {mine.run.seed}, {mine.run.threads} threads",
                flush=True,
            )
        say(f"building {args.num_envs} envs (settling their starts) ...", flush=True)
        env = make_env(mine, teacher)
        if mine.run.share_cores and not group.distributed:  # ranks: their --threads share
            env.sharing = SharedCores(torch.get_num_threads())
        say(f"  ready in {time.perf_counter() - clock:.1f} s", flush=True)
        runner_class = SafeDistillationRunner if teacher else SafeRunner
        writes = str(log_dir) if group.main else None
        runner = runner_class(env, rsl_rl_config(args, teacher), log_dir=writes, device="cpu")
        hashes = os.environ.get(distributed.PARAMETER_HASHES_ENV)
        if hashes:
            distributed.record_parameter_hashes(runner, hashes, group)
        if resume is None:
            start_as_base_gait(runner)  # learn() then broadcasts rank 0's parameters
            if teacher is not None:  # its actor (and with --distill-levels its curriculum)
                levels = args.train.distill_levels
                runner.load(str(teacher.path), data=setup.teacher_data, env_state=levels)
                if levels and env.core.terrain_map is not None:
                    env.core.reset()  # every env restarts on its teacher's level
                say(f"distilling the teacher {teacher.path}")
            if setup.warm_start is not None:  # its models; this run's optimizer
                _warm_start(runner, setup, args.train.warm_start_levels)
                critic = setup.warm_start.critic
                say(f"warm start from {setup.warm_start.actor}"
                    + (f", its critic from {critic}" if critic else ""))  # fmt: skip
        else:  # every rank loads rank 0's file
            runner.load(str(resume[0]), data=setup.resume_data)
            if env.core.terrain_map is not None:
                env.core.reset()  # every env restarts on its level of the resumed curriculum
            runner.current_learning_iteration += 1  # continue after the saved iteration
            say(f"resumed from {resume[0]}: next iteration {runner.current_learning_iteration}")
        if group.main:
            note = write_record(log_dir / "config.json", args, TRAINER,
                                resume and resume[0].parent / "config.json")  # fmt: skip
            if note:
                say(f"note: {note}")
        checkpoint = _learn(args.run, runner, group, clock, _stages(args, runner, say))
        if args.run.logger == "wandb" and group.main:
            from rwalk.rl.wandb_writer import WandbWriter

            WandbWriter.finish()  # the stage's W&B run ends with it
        if args.run.export and group.main:
            jit_path, onnx_path = export_policy(runner, log_dir / "exported")
            print(f"[rwalk] exported {jit_path} and {onnx_path} (layout: policy.json)")
    return checkpoint, args, teacher


def _stages(args: Training, runner, say) -> list[tuple[int, Callable[[int], None]]]:
    """The run's last stages, each as (its first iteration, what begins it at an
    iteration): the model's physics (--nominal-physics-iterations, where the physics is
    randomised) and the reward's late values (--late-iterations)."""
    train, end = args.train, args.run.max_iterations
    stages = []
    if train.nominal_physics_iterations and runner.env.core.physics.randomization is not None:
        stages.append((end - train.nominal_physics_iterations, functools.partial(
            _nominal_physics, runner, train.nominal_physics_keep,
            train.nominal_physics_entropy_coef, say=say)))  # fmt: skip
    if train.late_iterations:
        stages.append((end - train.late_iterations,
                       functools.partial(_late_reward, runner, train, say=say)))  # fmt: skip
    until, first = min(train.flat_until or end, end), runner.current_learning_iteration
    if train.flat_kinds and until > first:  # a resume past the window's end leaves the
        stages.append((train.flat_from, functools.partial(  # levels its checkpoint has
            _flat_kinds, runner, train.flat_kinds, True, say=say)))  # fmt: skip
    if train.flat_kinds and first <= until < end:
        stages.append((until, functools.partial(
            _flat_kinds, runner, train.flat_kinds, False, say=say)))  # fmt: skip
    return stages


def _flat_kinds(runner, kinds: tuple[str, ...], flat: bool, iteration: int, *, say) -> None:
    """From their next episode on, the envs on ``kinds`` walk level 0 and stay there
    (``flat``), or walk the curriculum again, each from a drawn level."""
    curriculum = runner.env.core.curriculum
    envs = int((curriculum.flatten if flat else curriculum.release)(kinds).sum())
    what = "walk level 0" if flat else "walk the curriculum again from drawn levels"
    say(f"[rwalk] iteration {iteration}: the {envs} envs on {', '.join(kinds)} tiles {what}",
        flush=True)  # fmt: skip


def _nominal_physics(runner, keep: tuple[str, ...], entropy: float | None, iteration: int,
                     *, say) -> None:  # fmt: skip
    """From now on new episodes draw the model's own physics but for the ranges ``keep``,
    and PPO's entropy bonus is ``entropy`` (None: as it was)."""
    physics = runner.env.core.physics
    ranges = physics.randomization
    physics.set_ranges(type(ranges).nominal(**{k: getattr(ranges, k) for k in keep}))
    but = f" but for {', '.join(keep)}" if keep else ""
    say(f"[rwalk] iteration {iteration}: new episodes draw the model's own physics{but}",
        flush=True)  # fmt: skip
    if entropy is not None:
        runner.alg.entropy_coef = entropy
        say(f"[rwalk] iteration {iteration}: entropy bonus {entropy:g}", flush=True)


def _late_reward(runner, train: TrainConfig, iteration: int, *, say) -> None:
    """From now on the reward has the late stage's values (the --late-* flags of
    ``LATE_VALUES``)."""
    runner.env.core.set_reward(**late_reward(train, runner.env.core.config))
    values = ", ".join(f"{flag(f'env.{part}.{field}')} {getattr(train, name):g}"
                       for name, (part, field) in LATE_VALUES.items()
                       if getattr(train, name) is not None)  # fmt: skip
    say(f"[rwalk] iteration {iteration}: the reward's late values {values}", flush=True)


def _after_updates(alg, due: dict[int, list[Callable[[], None]]]) -> None:
    """Call each of ``due[count]`` once, after ``alg``'s next ``count`` updates: rsl-rl's
    ``learn()`` updates once per iteration, after its rollout, so the next iteration
    collects with what they changed, without ending the call (and its checkpoint chunk)
    there."""
    if not due:
        return
    update, done, last = alg.update, [0], max(due)

    def counted(*args, **kwargs):
        result = update(*args, **kwargs)
        done[0] += 1
        if done[0] == last:
            alg.update = update
        for then in due.get(done[0], ()):
            then()
        return result

    alg.update = counted


def _learn(
    args: RunConfig,
    runner: SafeRunner,
    group: distributed.Group,
    clock: float,
    stages: list[tuple[int, Callable[[int], None]]] = (),
) -> Path:
    """``runner.learn`` in chunks up to each checkpoint, until --max-iterations or the
    time budget; each of ``stages`` (its first iteration, what begins it: ``_stages``)
    begins before its first iteration collects, or at the first where the run resumes
    past it. Returns the last checkpoint's path."""
    say = print if group.main else lambda *_, **__: None
    first = runner.current_learning_iteration
    budget = args.max_minutes * 60.0
    learning_since = time.perf_counter()  # per-iteration time excludes building the envs
    checkpoint = Path(args.log_dir) / f"model_{first}.pt"
    stages = [(max(start, first), begin) for start, begin in stages]  # resumed past one
    while runner.current_learning_iteration < args.max_iterations:
        it = runner.current_learning_iteration
        # One learn() call up to the next checkpoint: rsl-rl saves the multiples of
        # save_interval in its loop and the call's last iteration after it.
        last = min(-(-it // args.save_interval) * args.save_interval, args.max_iterations - 1)
        due: dict[int, list[Callable[[], None]]] = {}
        for start, begin in stages:
            if it <= start <= last:  # it begins before iteration ``start`` collects
                due.setdefault(start - it, []).append(functools.partial(begin, start))
        for begin in due.pop(0, ()):  # now; the others within the call
            begin()
        _after_updates(runner.alg, due)
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
