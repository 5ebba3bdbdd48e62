"""Train a policy with PPO built from TorchRL's own parts on the batched env.

    rwalk-train-torchrl
    rwalk-train-torchrl --num-envs 512 --max-iterations 200 --log-dir logs/torchrl
    rwalk-train-torchrl --no-robust          # the one rough world instead

(In a checkout without installing: python -m runners.train_torchrl ...)

The envs are rwalk-train's (rwalk.presets.TrainingEnv): by default the robust
world, its actor reading the policy's pieces with observation noise and its
critic the privileged ones too (rwalk.rl.config.observation_groups). A Collector
steps them (partial resets via "_reset"); GAE computes advantages; ClipPPOLoss
trains a TanhNormal actor and a value network on minibatches from a replay
buffer, each input normalised (ObservationNorm) and the reward scaled (see
rwalk.rl.torchrl_ppo). Flags that mean the same as rwalk-train's have its names.

Writes config.json ({"trainer": "torchrl", "args", "env"}) and checkpoints
torchrl_<n>.pt (the state after <n> iterations, every --save-interval, at the end
and when --max-minutes is spent; marked "trainer": "torchrl"), atomically, and
prints one progress line per iteration (with that iteration's frames/s, overall
and while collecting). A run folder belongs to one run, as with rwalk-train:
.rwalk.lock marks a run in progress, another run's checkpoints (of either trainer)
are refused unless --overwrite, and --resume goes on from a torchrl_<n>.pt (or a
folder's newest) with the run's own flags (only the run settings and --num-envs
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

from rwalk.cli import combine, command, explicit_fields, one_line_errors, parse_dataclass
from rwalk.presets import TrainingEnv
from rwalk.rl.checkpoints import CheckpointError, RunSetupError
from rwalk.rl.config import ConfigError, ResumeConflict, RunConfig
from rwalk.rl.torchrl_collect import WorkerDied
from rwalk.rl.torchrl_config import TorchRLConfig
from rwalk.rl.torchrl_ppo import train

__all__ = ["Args", "main"]


def _check(args) -> None:
    args.train.check_batch(args.num_envs)  # a minibatch holds a frame


#: rwalk-train-torchrl's flags: one per field of its three configs (``args.run``,
#: ``args.env``, ``args.train`` rebuild them); config.json stores them under "args".
Args = combine(
    "Args",
    {"run": RunConfig, "env": TrainingEnv, "train": TorchRLConfig},
    defaults={"log_dir": "logs/torchrl", "max_iterations": 50, "num_envs": 256},
    exclude=("export", "dist_timeout", "logger", "wandb_project", "run_name"),
    doc="A TorchRL PPO run: every field is a command-line flag (--num-envs, ...), checked on "
    "creation by the config it belongs to (RunConfig, TrainingEnv, TorchRLConfig).",
    namespace={"check": _check},
)


@one_line_errors("rwalk.runners.train_torchrl")
def main(argv: list[str] | None = None) -> None:
    """The ``rwalk-train-torchrl`` command."""
    prog = command("rwalk.runners.train_torchrl")
    args = parse_dataclass(Args, argv, __doc__, prog=prog)
    refused = (CheckpointError, ConfigError, FileNotFoundError, ResumeConflict, RunSetupError,
               WorkerDied)  # fmt: skip
    try:
        train(args, explicit_fields(Args, argv))
    except refused as error:  # a folder in use or another run's, a bad --resume, a worker lost
        raise SystemExit(f"{prog}: error: {error}") from None


if __name__ == "__main__":
    main()
