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

import argparse
import json
from pathlib import Path

from rwalk import learning_curves
from rwalk.cli import one_line_errors
from rwalk.tensorboard_events import read_scalars


@one_line_errors("rwalk.runners.plot_training")
def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("log_dir", type=Path, nargs="+", help="run folders (overlaid)")
    parser.add_argument(
        "--by-iteration", action="store_true", help="x axis: PPO iteration (default: minutes)"
    )
    parser.add_argument(
        "--paces", type=float, nargs="+", metavar="SECONDS",
        help="seconds per iteration of each run, measured alone (one per log_dir): x axis = "
        "iteration x pace, for runs that shared the cores",
    )  # fmt: skip
    parser.add_argument("--title", help="the figure's title")
    parser.add_argument("--out", type=Path, default=Path("docs/learning_curve.png"))
    parser.add_argument("--base-gait-json", type=Path, help="play.py --json output")
    args = parser.parse_args(argv)

    if args.paces is not None and (
        len(args.paces) != len(args.log_dir) or not all(0 < p < 1e6 for p in args.paces)
    ):
        parser.error(f"--paces needs one number of seconds > 0 per run folder "
                     f"({len(args.log_dir)}), got {args.paces}")  # fmt: skip
    runs = {str(log_dir): read_scalars(log_dir) for log_dir in args.log_dir}
    paces = None if args.paces is None else dict(zip(runs, args.paces, strict=True))
    base = None
    if args.base_gait_json:
        rows = json.loads(args.base_gait_json.read_text())
        base = next((r for r in rows if r["name"] == "base gait"), None)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    learning_curves.plot(runs, args.out, base, args.by_iteration, args.title, paces)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
