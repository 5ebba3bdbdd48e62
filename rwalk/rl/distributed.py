"""One training over several CPU processes: rsl-rl's data-parallel PPO on gloo, under torchrun.

    torchrun --standalone --nproc-per-node 2 -m runners.train --num-envs 512 ...
    torchrun --nnodes 2 --node-rank R --nproc-per-node 8 --rdzv-endpoint HOST:29400 \\
        -m runners.train --num-envs 512 ...                  # on each of 2 machines

rsl-rl-lib 5.5.1's PPO is already data-parallel through plain ``torch.distributed``
calls; only its runner's setup insists on ``cuda:LOCAL_RANK`` and NCCL. ``SafeRunner``
overrides that one method (``_configure_multi_gpu``) to join a gloo group on CPU
(``join``), so the algorithm runs unchanged. Each rank steps its own envs; rank 0
alone writes the run folder.

What the ranks exchange (all gloo collectives on CPU tensors):

- per env step, rsl-rl's observation normalisers (actor and critic): an all-reduce
  of the batch count, mean and variance, so every rank normalises alike;
- per minibatch, the actor and critic gradients (one all-reduce per 25 MB bucket,
  averaged) and the mean KL (adaptive learning rate, decided by rank 0 and broadcast);
- per ``learn()`` call (the start, and each chunk up to a checkpoint), every actor and
  critic tensor broadcast from rank 0;
- per chunk, rank 0's stop decision (``--max-minutes``), so all ranks stop together;
- at startup, each rank's settings (a mismatch refuses to start), rank 0's setup
  outcome (a folder in use, a bad ``--resume``: every rank fails with its message)
  and the bytes of the checkpoint to resume from.

Exchanged data is JSON or raw bytes in tensors, never pickles. Every collective
times out after ``--dist-timeout`` seconds; a rank that dies closes its
connections, so the others fail at their next collective and torchrun ends the
group with a report naming the first failure. A launcher that dies, even by SIGKILL,
takes its ranks with it (``exit_with_launcher``).
"""

from __future__ import annotations

import ctypes
import datetime
import hashlib
import json
import os
import signal
import sys
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

LAUNCHER_PID = os.getppid()
"""The process that started this one, read as this module loads: a rank's launcher
(torchrun's agent), read before torch loads (seconds, in which the launcher may die)."""


def _die_with_launcher() -> bool:
    """Have Linux kill this process (SIGKILL) when LAUNCHER_PID, its parent, dies (prctl's
    PR_SET_PDEATHSIG), and kill it now if that parent is already gone; False where Linux
    cannot be asked (another system)."""
    if not sys.platform.startswith("linux"):
        return False
    set_pdeathsig = 1
    if ctypes.CDLL(None, use_errno=True).prctl(set_pdeathsig, signal.SIGKILL, 0, 0, 0) != 0:
        return False
    if os.getppid() != LAUNCHER_PID:  # it died before the call: no signal will come
        os.kill(os.getpid(), signal.SIGKILL)
    return True


# A rank dies with its launcher from here on, before it spends seconds loading torch
# (exit_with_launcher).
if os.environ.get("WORLD_SIZE", "1").strip() not in ("", "0", "1"):
    _die_with_launcher()

import torch  # noqa: E402
import torch.distributed as dist  # noqa: E402

from rwalk.threads import cores  # noqa: E402

DEFAULT_TIMEOUT_S = 600.0
"""Seconds a rank waits in a collective for the others (``--dist-timeout``)."""
PARAMETER_HASHES_ENV = "RWALK_PARAMETER_HASHES"
"""Test hook: a folder where each rank appends ``<iteration> <sha256>`` of its actor and
critic state after every update to ``rank<r>.txt`` (``record_parameter_hashes``)."""


class GroupError(RuntimeError):
    """A process group that cannot start as asked (torchrun's variables, mismatched
    settings); the message names the variable or the ranks and settings at fault."""


@dataclass(frozen=True)
class Group:
    """This process's place in the training: torchrun's RANK, LOCAL_RANK, WORLD_SIZE and
    LOCAL_WORLD_SIZE (one process of one: not distributed)."""

    rank: int = 0
    """Global rank, 0 .. world_size - 1; rank 0 writes the run folder."""
    local_rank: int = 0
    """Rank among the processes on this machine."""
    world_size: int = 1
    """Processes in the training, all machines together."""
    local_world_size: int = 1
    """Processes on this machine: they share its cores."""

    @property
    def distributed(self) -> bool:
        return self.world_size > 1

    @property
    def main(self) -> bool:
        """Whether this is rank 0."""
        return self.rank == 0

    @classmethod
    def from_env(cls, environ: Mapping[str, str] | None = None) -> Group:
        """The group torchrun's environment variables describe; WORLD_SIZE unset or 1:
        a single process (``Group()``).

        Raises:
            GroupError: naming the variable, if one is missing, not an integer or out of range.
        """
        env = os.environ if environ is None else environ
        world = _env_int(env, "WORLD_SIZE", "1")
        if world < 1:
            raise GroupError(f"WORLD_SIZE must be >= 1, got {world}")
        if world == 1:
            return cls()
        group = cls(
            rank=_env_int(env, "RANK"),
            local_rank=_env_int(env, "LOCAL_RANK"),
            world_size=world,
            local_world_size=_env_int(env, "LOCAL_WORLD_SIZE"),
        )
        if not 0 <= group.rank < world:
            raise GroupError(f"RANK must be in [0, WORLD_SIZE={world}), got {group.rank}")
        if not 1 <= group.local_world_size <= world:
            raise GroupError(
                f"LOCAL_WORLD_SIZE must be in [1, WORLD_SIZE={world}], got {group.local_world_size}"
            )
        if not 0 <= group.local_rank < group.local_world_size:
            raise GroupError(
                f"LOCAL_RANK must be in [0, LOCAL_WORLD_SIZE={group.local_world_size}), "
                f"got {group.local_rank}"
            )
        return group


def _env_int(env: Mapping[str, str], name: str, default: str | None = None) -> int:
    value = env.get(name, default)
    if value is None:
        raise GroupError(
            f"{name} is not set but WORLD_SIZE={env.get('WORLD_SIZE')} asks for several "
            "processes: start them with torchrun (python -m torch.distributed.run)"
        )
    try:
        return int(value)
    except ValueError:
        raise GroupError(f"{name} must be an integer, got {value!r}") from None


def default_threads(group: Group) -> int:
    """Physics threads of a rank when --threads is 0: this machine's cores shared by its
    ranks (never oversubscribed), at least 1."""
    return max(1, cores() // group.local_world_size)


WATCH_INTERVAL_S = 0.5
"""Seconds between two looks at the launcher, where Linux cannot watch it."""
GRACE_S = 3.0
"""Seconds a rank whose launcher died may take to end on its own, where Linux cannot
watch the launcher."""
_ending = False
"""Whether this rank is ending: its first SIGTERM was raised, or it left its group."""
_watching = False
"""Whether the watchdog thread runs."""


def exit_with_launcher() -> None:
    """End this rank when the process that launched it (torchrun's agent) dies, even by
    SIGKILL and whatever the rank is doing: without it the ranks train on in their own
    sessions, rank 0 holding the run folder's lock, and join no group again.

    On Linux, the kernel kills the rank with its launcher (``PR_SET_PDEATHSIG``), asked
    as this module loads, before the rank loads torch, so a launcher killed in the
    seconds a rank starts in is caught too; if the launcher died before, the rank
    ends then. Killed so, rank 0 leaves its lock behind, which the next training in the
    folder takes over (its pid no longer runs: ``rwalk.rl.checkpoints.run_lock``).
    Linux sends that signal when the launcher's *thread* that started the rank ends:
    torchrun starts its ranks from its main thread. Not caught: a launcher that dies in
    the fraction of a second before this module loads, which leaves the rank waiting in
    ``join`` for a store that is gone, until --dist-timeout.

    Elsewhere, a watchdog thread compares the parent's pid with LAUNCHER_PID every
    WATCH_INTERVAL_S seconds; once the launcher is gone it sends the rank a SIGTERM,
    and ends it outright GRACE_S seconds later.

    A SIGTERM (torchrun ending the group after a rank failed) raises ``SystemExit`` once,
    so that ``finally`` blocks run (rank 0 releases its lock); later ones, and any after
    the rank left its group (``leave``), are ignored: they would land in its teardown
    (an env's ``__del__``) and print a traceback after its one-line error.
    """
    global _watching
    signal.signal(signal.SIGTERM, _end)
    if _watching or _die_with_launcher():
        return
    _watching = True

    def watch() -> None:
        while os.getppid() == LAUNCHER_PID:
            time.sleep(WATCH_INTERVAL_S)
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(GRACE_S)
        os._exit(1)

    threading.Thread(target=watch, name="rwalk-launcher-watch", daemon=True).start()


def _end(signum, frame) -> None:
    """SIGTERM's handler (``exit_with_launcher``)."""
    global _ending
    if _ending:
        return
    _ending = True
    raise SystemExit(f"rank {os.getpid()}: ended (signal {signum}: the launcher is gone "
                     "or ended the group)")  # fmt: skip


def join(group: Group, timeout_s: float = DEFAULT_TIMEOUT_S) -> None:
    """Join the gloo process group (MASTER_ADDR / MASTER_PORT or torchrun's store); a
    no-op for a single process or a group already joined. Every collective then fails
    after ``timeout_s`` seconds without the other ranks."""
    if not group.distributed or dist.is_initialized():
        return
    dist.init_process_group(
        backend="gloo",
        rank=group.rank,
        world_size=group.world_size,
        timeout=datetime.timedelta(seconds=timeout_s),
    )


def leave() -> None:
    """Leave the process group, if this process joined one: the rank is ending, and a
    SIGTERM no longer interrupts it (``exit_with_launcher``)."""
    global _ending
    _ending = True
    if dist.is_initialized():
        dist.destroy_process_group()


def is_group_failure(error: BaseException) -> bool:
    """Whether ``error`` is a collective that failed (a rank gone, a timeout): torch's
    ``DistError``, or gloo's transport errors, which reach Python as plain ``RuntimeError``s
    naming their gloo source file ("...gloo/transport/tcp/pair.cc: Connection closed by
    peer", "... Timed out waiting 5000ms for send operation to complete")."""
    return isinstance(error, dist.DistError) or (
        isinstance(error, RuntimeError) and "gloo" in str(error)
    )


def multi_gpu_config(group: Group) -> dict[str, int] | None:
    """rsl-rl's ``cfg["multi_gpu"]``: None for one process, else the ranks and world size
    (its PPO reads ``global_rank`` and ``world_size``)."""
    if not group.distributed:
        return None
    return {
        "global_rank": group.rank,
        "local_rank": group.local_rank,
        "world_size": group.world_size,
    }


# ------------------------------------------------------------------- exchanges
def broadcast_bytes(group: Group, data: bytes | None) -> bytes:
    """Rank 0's ``data`` on every rank (others pass None); a single process gets its own."""
    if not group.distributed:
        assert data is not None
        return data
    sent = _as_tensor(data or b"") if group.main else None
    size = torch.tensor([0 if sent is None else sent.numel()], dtype=torch.int64)
    dist.broadcast(size, src=0)
    buffer = torch.empty(int(size.item()), dtype=torch.uint8) if sent is None else sent
    if buffer.numel():
        dist.broadcast(buffer, src=0)
    return buffer.numpy().tobytes()


def _as_tensor(data: bytes) -> torch.Tensor:
    """``data`` as a uint8 tensor (a copy). Shape: (len(data),)."""
    if not data:
        return torch.empty(0, dtype=torch.uint8)
    return torch.frombuffer(bytearray(data), dtype=torch.uint8)


def broadcast_json(group: Group, value: Any = None) -> Any:
    """Rank 0's JSON-able ``value`` on every rank (others' values are ignored)."""
    if not group.distributed:
        return value
    data = json.dumps(value).encode("utf-8") if group.main else None
    return json.loads(broadcast_bytes(group, data))


def all_gather_json(group: Group, value: Any) -> list[Any]:
    """Every rank's JSON-able ``value``, by rank."""
    if not group.distributed:
        return [value]
    data = _as_tensor(json.dumps(value).encode("utf-8"))
    sizes = [torch.zeros(1, dtype=torch.int64) for _ in range(group.world_size)]
    dist.all_gather(sizes, torch.tensor([data.numel()], dtype=torch.int64))
    longest = int(max(size.item() for size in sizes))
    padded = torch.zeros(longest, dtype=torch.uint8)
    padded[: data.numel()] = data
    gathered = [torch.empty(longest, dtype=torch.uint8) for _ in range(group.world_size)]
    dist.all_gather(gathered, padded)
    return [
        json.loads(buffer[: int(size.item())].numpy().tobytes())
        for buffer, size in zip(gathered, sizes, strict=True)
    ]


def agree(group: Group, decision: bool) -> bool:
    """Rank 0's ``decision`` on every rank (a stop that all ranks take at the same iteration)."""
    if not group.distributed:
        return decision
    flag = torch.tensor([int(decision)], dtype=torch.int64)
    dist.broadcast(flag, src=0)
    return bool(flag.item())


def raise_if_failed(group: Group, failure: BaseException | None, known: tuple[type, ...]) -> None:
    """Rank 0 ran a step the others wait for; raise its ``failure`` on every rank.

    Rank 0 re-raises its own exception; the other ranks raise the same class when it is
    one of ``known`` (else ``GroupError``) with rank 0's message. A single process just
    re-raises ``failure``.
    """
    if not group.distributed:
        if failure is not None:
            raise failure
        return
    sent = None if failure is None else [type(failure).__name__, str(failure)]
    received = broadcast_json(group, sent if group.main else None)
    if received is None:
        return
    if group.main:
        assert failure is not None
        raise failure
    name, message = received
    kind = next((k for k in known if k.__name__ == name), None)
    raise (kind or GroupError)(message if kind else f"rank 0 failed: {name}: {message}")


def check_same_settings(group: Group, settings: dict[str, Any]) -> None:
    """Refuse to start unless every rank has rank 0's ``settings`` (JSON-able: flags,
    library versions).

    Raises:
        GroupError: on every rank, naming each differing rank and setting with both values.
    """
    everyone = all_gather_json(group, settings)
    reference = everyone[0]
    differences = []
    for rank, theirs in enumerate(everyone[1:], start=1):
        for key in sorted(set(reference) | set(theirs)):
            if reference.get(key) != theirs.get(key):
                differences.append(
                    f"rank {rank} has {key} {theirs.get(key)!r} (rank 0: {reference.get(key)!r})"
                )
    if differences:
        raise GroupError(
            "the ranks were started with different settings, so they would not train one "
            "policy: " + "; ".join(differences) + ". Start every rank with the same command "
            "and the same library versions"
        )


def record_parameter_hashes(runner, folder: str, group: Group) -> None:
    """Test hook (``RWALK_PARAMETER_HASHES``): after every update, append
    ``<iteration> <sha256 of the actor and critic state>`` (a distilled student's: of the
    student) to ``folder/rank<r>.txt`` (hashed as rsl-rl logs the iteration, right after
    its update)."""
    path = Path(folder) / f"rank{group.rank}.txt"
    path.parent.mkdir(parents=True, exist_ok=True)
    log = runner.logger.log

    def hash_and_log(*args, **kwargs):
        digest = hashlib.sha256()
        names = ("actor", "critic") if hasattr(runner.alg, "actor") else ("student",)
        for model in (getattr(runner.alg, name) for name in names):
            for name, tensor in model.state_dict().items():
                digest.update(name.encode())
                digest.update(tensor.detach().contiguous().numpy().tobytes())
        with path.open("a") as file:
            file.write(f"{kwargs['it']} {digest.hexdigest()}\n")
        return log(*args, **kwargs)

    runner.logger.log = hash_and_log


__all__ = [
    "DEFAULT_TIMEOUT_S",
    "PARAMETER_HASHES_ENV",
    "Group",
    "GroupError",
    "agree",
    "all_gather_json",
    "broadcast_bytes",
    "broadcast_json",
    "check_same_settings",
    "cores",
    "default_threads",
    "exit_with_launcher",
    "is_group_failure",
    "join",
    "leave",
    "multi_gpu_config",
    "raise_if_failed",
    "record_parameter_hashes",
]
