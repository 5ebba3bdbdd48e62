"""Learning curves of a training run from its TensorBoard events.

    python -m runners.plot_training logs/rwalk --out docs/learning_curve.png \
        --base-gait-json docs/eval.json
    python -m runners.plot_training logs/a logs/b --by-iteration --out curves.png  # overlaid

Plots, per iteration, the mean over episodes that ended of forward velocity,
velocity-tracking error, fall rate and return per step (rsl-rl's
Train/mean_reward is per episode), with the base gait's evaluated levels as
dashed lines when given.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import tyro

from rwalk import learning_curves
from rwalk.cli import command, one_line_errors, parse, usage_error
from rwalk.tensorboard_events import read_scalars

#: Longest pace of an iteration. Seconds.
MAX_PACE = 1e6


@dataclass(frozen=True)
class PlotTrainingArgs:
    """rwalk-plot-training's command line (each field a flag; the run folders come first)."""

    log_dir: Annotated[tuple[Path, ...], tyro.conf.Positional, tyro.conf.arg(metavar="LOG_DIR")]
    """run folders (overlaid)"""
    by_iteration: bool = False
    """x axis: PPO iteration, not minutes"""
    paces: tuple[float, ...] | None = None
    """seconds per iteration of each run, measured alone, one per LOG_DIR: x = iteration x pace"""
    title: str | None = None
    """the figure's title"""
    out: Path = Path("docs/learning_curve.png")
    """the figure (PNG)"""
    base_gait_json: Path | None = None
    """rwalk-play --json output: the base gait's levels as dashed lines"""

    def __post_init__(self) -> None:
        if not self.log_dir:
            raise ValueError("LOG_DIR: give at least one run folder")


def parse_args(argv: list[str] | None = None) -> PlotTrainingArgs:
    """``argv`` as rwalk-plot-training's arguments; exits 2 with one line naming a bad flag."""
    prog = command("rwalk.runners.plot_training")
    args = parse(PlotTrainingArgs, argv, prog=prog, description=__doc__)
    paces = args.paces
    if paces is not None and (
        len(paces) != len(args.log_dir) or not all(0 < p < MAX_PACE for p in paces)
    ):
        usage_error(prog, f"--paces needs one number of seconds > 0 per run folder "
                          f"({len(args.log_dir)}), got {list(paces)}")  # fmt: skip
    return args


@one_line_errors("rwalk.runners.plot_training")
def main(argv: list[str] | None = None) -> None:
    """Console script ``rwalk-plot-training`` (returns None: its exit status is 0)."""
    args = parse_args(argv)
    runs = {str(log_dir): read_scalars(log_dir) for log_dir in args.log_dir}
    paces = None if args.paces is None else dict(zip(runs, args.paces, strict=True))
    base = None
    if args.base_gait_json:
        rows = json.loads(args.base_gait_json.read_text())
        base = next((r for r in rows if r["name"] == "base gait"), None)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    learning_curves.plot(runs, args.out, base, args.by_iteration, args.title, paces)
    print(f"wrote {args.out}")


if __name__ == "__main__":  # through the module by name, where tyro reads the Args' types
    from rwalk.runners.plot_training import main as plot_main

    plot_main()
