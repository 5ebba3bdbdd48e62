"""Train a policy for a task with rsl-rl's PPO on the batched env.

    rwalk-train                                  # the default: a teacher, then its student (README)
    rwalk-train --recipe plain                   # PPO alone, 300 iterations
    rwalk-train --task adaptive_gait             # its default: a teacher, then its student
    rwalk-train --task adaptive_gait --recipe plain --command-range 0.05 0.25
    rwalk-train --max-minutes 30 --max-iterations 100000
    rwalk-train --resume logs/rwalk --max-iterations 200     # newest checkpoint there
    rwalk-train --resume logs/rwalk/model_49.pt --max-iterations 200

(In a checkout without installing: python -m runners.train ...)

One training over several processes, on one machine or several (rsl-rl's
data-parallel PPO on gloo; see rwalk.rl.distributed):

    torchrun --standalone --nproc-per-node 2 -m runners.train --num-envs 512
    torchrun --nnodes 2 --node-rank R --nproc-per-node 8 --rdzv-endpoint HOST:29400 \\
        -m runners.train --num-envs 512     # on each machine, R = 0, 1

Each rank steps its own --num-envs envs (2 ranks x 512: 1024 envs per rollout)
with its own seed stream and its share of the machine's cores; rank 0 alone
writes the run folder (checkpoints, config.json, TensorBoard, exports) and holds
its lock. Every rank must be started with the same flags (only --threads may
differ): ranks that differ refuse to start, naming the flags.

Every flag is a field of the training's configs (rwalk.rl.config.Training): the
preset (--task, --robust/--no-robust, --costs, --recipe) picks the task, the world and,
for a robust world, the task's recipe (--recipe precise; residual_walk: a teacher that
reads the physics and the ground under its feet, then its blind GRU student in
LOG_DIR/student, with the gait costs and the speed kernel, servos drawn from 0.75-1.15
of their gain and torque, 0-3 substeps of latency and actions of +-30 mm;
adaptive_gait: docs/adaptive.md's default, the gait the command asks for, a teacher and
its student; each of its values a flag that may be set; rwalk.tasks.base.Recipe); every
field of the task's env config is a flag of its own (--env.costs.clearance 3000,
--env.randomization.friction 0.5 1.3, --env.terrain-levels.demote 0.3; short names
for common ones: --settle-steps, --command-range, --terrain-kinds, ...); rsl-rl's
algorithm and models (--hidden-dims, --learning-rate, ...) and the run's settings
(--log-dir, --max-iterations, ...). config.json records the resolved configs
(schema 2), and play, the reports, export, resume and distillation build from
it. --resume goes on with the run's own record: only the run settings (--log-dir,
--seed, --resume, --overwrite, --max-iterations, --max-minutes, --save-interval,
--threads, --export, --dist-timeout, --logger, --wandb-project, --run-name) and
--num-envs may change; another value of any other field is refused, naming it. It
writes to the resumed run's folder with the run's seed and --max-iterations unless
--log-dir, --seed or --max-iterations name others.

--logger wandb sends the metrics to Weights & Biases as well (rsl-rl's writer; pip
install 'rwalk[wandb]'; WANDB_MODE=offline keeps them local): one W&B run per
run folder, named --run-name (default: the --log-dir folder's name; a
--student-iterations student stage: that name + "-student"), continued by --resume,
its files in LOG_DIR/wandb.

Writes to --log-dir: TensorBoard events (every reward term, episode length, fall
rate, forward velocity, terrain levels), checkpoints, config.json, and at the
end exported/policy.pt (TorchScript) and exported/policy.onnx. Iterations count
from 0; model_<it>.pt holds the state after iteration <it>, and is written for
every <it> that is a multiple of --save-interval and for the last iteration
(--save-interval 3, 7 iterations: model_0.pt, model_3.pt, model_6.pt).
Checkpoints and config.json are written atomically: a killed run leaves only
complete checkpoints. A folder with checkpoints belongs to one run: train there
again only with --resume (continuing at <it> + 1) or --overwrite; .rwalk.lock in
it marks a run in progress.
"""

from __future__ import annotations

from rwalk.cli import command, one_line_errors
from rwalk.rl import distributed, training
from rwalk.rl.command import parse_training
from rwalk.rl.config import Training
from rwalk.rl.record import read_record

Args = Training
"""rwalk-train's command line: a ``Training`` (every nested field a flag)."""
PROG = command("rwalk.runners.train")
"""The command in usage lines and error messages."""


def parse_args(argv: list[str] | None = None) -> Training:
    """``argv`` (None: ``sys.argv[1:]``) as the training it asks for, resolved."""
    return parse_training(Training, argv, PROG, __doc__, read_record)


@one_line_errors("rwalk.runners.train")
def main(argv: list[str] | None = None) -> None:
    """The ``rwalk-train`` command; a run that cannot start exits with a one-line error
    (under torchrun, naming the rank), and so does a rank whose group failed."""
    args = parse_args(argv)
    where = ""
    try:
        group = distributed.Group.from_env()
        if group.distributed:
            where = f"rank {group.rank} of {group.world_size}: "
        training.train(args)
    except (*training.SETUP_ERRORS, distributed.GroupError) as error:
        raise SystemExit(f"{PROG}: error: {where}{error}") from None
    except RuntimeError as error:
        if not (where and distributed.is_group_failure(error)):
            raise
        raise SystemExit(
            f"{PROG}: error: {where}the training's process group failed: another rank died, "
            f"or did not answer within --dist-timeout {args.run.dist_timeout:g} s "
            f"({type(error).__name__}: {error})"
        ) from None


if __name__ == "__main__":
    main()
