"""Train a policy with PPO built from TorchRL's own parts on the batched env.

    rwalk-train-torchrl
    rwalk-train-torchrl --num-envs 512 --max-iterations 200 --log-dir logs/torchrl
    rwalk-train-torchrl --no-robust          # the one rough world instead

(In a checkout without installing: python -m runners.train_torchrl ...)

The envs are rwalk-train's (the preset and --env.* flags): by default the robust
world, its actor reading the policy's pieces with observation noise and its
critic the privileged ones too (rwalk.rl.config.observation_groups). A Collector
steps them (partial resets via "_reset"); GAE computes advantages; ClipPPOLoss
trains a TanhNormal actor and a value network on minibatches from a replay
buffer, each input normalised (ObservationNorm) and the reward scaled (see
rwalk.rl.torchrl_ppo). Flags that mean the same as rwalk-train's have its names.

Writes config.json (the run's record, "trainer": "torchrl") and checkpoints
torchrl_<n>.pt (the state after <n> iterations, every --save-interval, at the end
and when --max-minutes is spent; marked "trainer": "torchrl"), atomically, and
prints one progress line per iteration (with that iteration's frames/s, overall
and while collecting). A run folder belongs to one run, as with rwalk-train:
.rwalk.lock marks a run in progress, another run's checkpoints (of either trainer)
are refused unless --overwrite, and --resume goes on from a torchrl_<n>.pt (or a
folder's newest) with the run's own record (only the run settings and --num-envs
may change).

Several collector workers (rwalk.rl.torchrl_collect):

    rwalk-train-torchrl --collectors 2                        # 2 local processes
    rwalk-train-torchrl --collectors 2 --backend distributed  # torch.distributed, gloo
    rwalk-train-torchrl --collectors 2 --backend ray          # pip install -e ".[ray]"

--num-envs is per worker: a batch holds collectors x num_envs x num_steps_per_env
frames. Each worker has its own env seeds and --threads physics threads (default
cores // collectors); policy weights go to the workers after every update.
"""

from __future__ import annotations

from rwalk.cli import command, one_line_errors
from rwalk.rl.checkpoints import CheckpointError, RunSetupError
from rwalk.rl.command import parse_training
from rwalk.rl.config import ResumeConflict
from rwalk.rl.record import ConfigError, read_record
from rwalk.rl.torchrl_collect import WorkerDied
from rwalk.rl.torchrl_config import TorchRLTraining
from rwalk.rl.torchrl_ppo import TRAINER, train

__all__ = ["Args", "main", "parse_args"]

Args = TorchRLTraining
"""rwalk-train-torchrl's command line: a ``TorchRLTraining`` (every nested field a flag)."""


def parse_args(argv: list[str] | None = None) -> TorchRLTraining:
    """``argv`` as the training it asks for."""
    prog = command("rwalk.runners.train_torchrl")
    return parse_training(TorchRLTraining, argv, prog, __doc__,
                          lambda path: read_record(path, TRAINER, TorchRLTraining))  # fmt: skip


@one_line_errors("rwalk.runners.train_torchrl")
def main(argv: list[str] | None = None) -> None:
    """The ``rwalk-train-torchrl`` command."""
    prog = command("rwalk.runners.train_torchrl")
    args = parse_args(argv)
    refused = (CheckpointError, ConfigError, FileNotFoundError, ResumeConflict, RunSetupError,
               WorkerDied)  # fmt: skip
    try:
        train(args)
    except refused as error:  # a folder in use or another run's, a bad --resume, a worker lost
        raise SystemExit(f"{prog}: error: {error}") from None


if __name__ == "__main__":
    main()
