"""A run's policy averaged over its saved checkpoints (weights averaged after the fact).

    rwalk-average logs/adaptive/student --first 100   # -> logs/adaptive/student/average_100-189.pt

The policy's weights (a distilled student's, or PPO's actor) are the mean of those of
every rwalk-train checkpoint model_<it>.pt of RUN with --first <= it <= --last; the rest
(normaliser statistics, critic or teacher, optimizer, iteration) is the newest's. The
result is written into RUN, beside the config.json that describes it, under a name that
--resume never takes for a checkpoint, and every evaluation command reads it like any
other checkpoint. On the adaptive task's students it took out about the part of rougher
ground's error that moves from checkpoint to checkpoint (2.5 mm/s), not the part that
stays with a student's seed, and moved no row's mean (docs/adaptive.md, "A student's
weights averaged over its last checkpoints").
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import tyro

from rwalk.cli import command, one_line_errors, parse, usage_error
from rwalk.evaluation import check_policy
from rwalk.rl.checkpoints import (
    CHECKPOINT_NAME,
    TRAINER,
    average_policy,
    check_outputs,
    checkpoint_files,
    save_checkpoint,
)
from rwalk.validation import require_at_least

PROG = command("rwalk.runners.average")
"""The command in usage lines and error messages."""


@dataclass(frozen=True)
class AverageArgs:
    """rwalk-average's command line (each field a flag; the run folder comes first)."""

    run: Annotated[Path, tyro.conf.Positional, tyro.conf.arg(metavar="RUN")]
    """the run folder (rwalk-train's --log-dir, or its student/)"""
    first: int = 0
    """the first iteration averaged"""
    last: int | None = None
    """the last iteration averaged (None: the newest checkpoint's)"""
    out: str | None = None
    """the file's name in RUN (None: average_<first>-<last>.pt)"""

    def __post_init__(self) -> None:
        require_at_least(self, 0, "first")
        if self.last is not None and self.last < self.first:
            raise ValueError(f"--last ({self.last}) must be >= --first ({self.first})")


def parse_args(argv: list[str] | None = None) -> AverageArgs:
    """``argv`` as rwalk-average's arguments; exits 2 with one line naming a bad flag."""
    args = parse(AverageArgs, argv, prog=PROG, description=__doc__)
    if not (args.run / "config.json").is_file():
        usage_error(PROG, f"RUN: {str(args.run)!r} holds no config.json: not an rwalk-train run "
                          f"folder")  # fmt: skip
    if args.out is not None and (
        Path(args.out).name != args.out or CHECKPOINT_NAME.fullmatch(args.out)
        or not args.out.endswith(".pt")
    ):  # fmt: skip
        usage_error(PROG, f"--out must be a file name ending in .pt, without a folder, that is not "
                          f"a checkpoint's (model_<it>.pt), got {args.out!r}")  # fmt: skip
    return args


def chosen(args: AverageArgs) -> list[tuple[int, Path]]:
    """The checkpoints of ``args.run`` from --first to --last, oldest first.

    Raises:
        ValueError: fewer than two, naming the range and what the folder holds.
    """
    found = checkpoint_files(args.run, TRAINER)
    last = args.last if args.last is not None else max((it for it, _ in found), default=0)
    picked = [(it, path) for it, path in found if args.first <= it <= last]
    if len(picked) < 2:
        held = ", ".join(str(it) for it, _ in found) or "none"
        raise ValueError(f"{str(args.run)!r} holds {len(picked)} checkpoint(s) of iterations "
                         f"{args.first}-{last} (its iterations: {held}); averaging needs two "
                         "or more")  # fmt: skip
    return picked


@one_line_errors("rwalk.runners.average")
def main(argv: list[str] | None = None) -> None:
    """Console script ``rwalk-average`` (returns None: its exit status is 0)."""
    args = parse_args(argv)
    picked = chosen(args)
    out = args.run / (args.out or f"average_{picked[0][0]}-{picked[-1][0]}.pt")
    check_outputs(PROG, {"--out": out})
    save_checkpoint(average_policy([path for _, path in picked]), out)
    try:
        check_policy(out)  # it loads as a policy of its run, as every evaluation will load it
    except BaseException:
        out.unlink()
        raise
    print(f"wrote {out}: the policy averaged over iterations "
          f"{', '.join(str(it) for it, _ in picked)}")  # fmt: skip


if __name__ == "__main__":  # through the module by name, where tyro reads AverageArgs's types
    from rwalk.runners.average import main as average_main

    average_main()
