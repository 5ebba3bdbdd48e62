"""The robustness benchmark: the base gait and policies under conditions never used in training.

    rwalk-robustness --checkpoint logs/robust/model_600.pt \\
        --checkpoint today=logs/res_t06/model_475.pt --episodes 100 --json docs/robustness.json \\
        --plot docs/robustness.png

Every row of a condition runs the same --episodes paired episodes: episode i
starts like a single env seeded --seed + i, with the same drawn physics and the
same kicks, whichever policy walks (a policy of either task: each walks on an env of its
own task, the base gait on the residual task's). The conditions, floors, table and plot are
``rwalk.robustness``'s: nominal, new maps, rougher ground, low and high friction,
payload, weak servos, pushes and latency. Prints one table per condition with
each policy's floors, writes every row to --json and, with --plot, a bar chart.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

from rwalk.cli import NATURAL_INT, POSITIVE_INT, command, one_line_errors
from rwalk.config import EnvConfig
from rwalk.evaluation import check_policy
from rwalk.levels import TerrainLevels
from rwalk.rl.checkpoints import atomic_write_text
from rwalk.robustness import CONDITIONS, condition_config, plot, read_rows, run_condition, table


def _checkpoint(text: str) -> tuple[str, Path]:
    """``LABEL=PATH`` or ``PATH`` (labelled by its run folder's name)."""
    label, _, path = text.rpartition("=")
    path = Path(path)
    if not path.is_file():
        raise argparse.ArgumentTypeError(f"checkpoint {str(path)!r} not found")
    return (label or path.parent.name), path


@one_line_errors("rwalk.runners.robustness")
def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        prog=command("rwalk.runners.robustness"), description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )  # fmt: skip
    add = parser.add_argument
    add(
        "--checkpoint",
        type=_checkpoint,
        action="append",
        default=[],
        help="[LABEL=]PATH of an rwalk-train checkpoint (repeat for several)",
    )
    add("--episodes", type=POSITIVE_INT, default=100, help="paired episodes per condition")
    add("--seed", type=NATURAL_INT, default=1000, help="first episode's seed")
    add("--map-level", type=NATURAL_INT, default=6, help="level of the 'new maps' condition")
    add("--max-steps", type=POSITIVE_INT, default=1000, help="episode length (env steps)")
    add("--settle-steps", type=NATURAL_INT, default=500, help="settling before each episode")
    add(
        "--conditions",
        nargs="+",
        default=list(CONDITIONS),
        choices=list(CONDITIONS),
        metavar="NAME",
        help=f"conditions to run (default: all of {list(CONDITIONS)})",
    )
    add("--json", type=Path, help="write every row here")
    add("--plot", type=Path, help="write the bar chart here (PNG)")
    add("--tables", type=Path, help="only print the table (and --plot) of a written --json")
    args = parser.parse_args(argv)  # fmt: skip
    if args.tables:
        try:
            rows = read_rows(args.tables)
        except (OSError, ValueError) as error:
            parser.error(f"--tables: {error}")
    else:
        try:
            TerrainLevels().check_level(args.map_level)
        except ValueError as error:
            parser.error(f"--map-level: {error}")
        for label, path in args.checkpoint:  # every file, before any row runs
            try:
                check_policy(path)
            except (OSError, ValueError) as error:
                parser.error(f"--checkpoint {label}: {error}")
        policies: dict[str, Path | None] = {"base gait": None, **dict(args.checkpoint)}
        rows = []
        for name in args.conditions:

            def config(name: str = name, **acts: str) -> EnvConfig:
                return condition_config(
                    name, args.map_level, args.max_steps, args.settle_steps, **acts
                )

            rows += run_condition(name, policies, args.episodes, args.seed, config)
            print(table([r for r in rows if r.condition == name]).split("\n", 2)[2], flush=True)
        if args.json:
            data = {
                "episodes": args.episodes, "seed": args.seed, "map_level": args.map_level,
                "max_steps": args.max_steps, "settle_steps": args.settle_steps,
                "conditions": {name: CONDITIONS[name][0] for name in args.conditions},
                "checkpoints": {label: str(path) for label, path in args.checkpoint},
                "rows": [dataclasses.asdict(r) for r in rows],
            }  # fmt: skip
            args.json.parent.mkdir(parents=True, exist_ok=True)
            atomic_write_text(args.json, json.dumps(data, indent=2))
    print(table(rows))
    if args.plot:
        args.plot.parent.mkdir(parents=True, exist_ok=True)
        plot(rows, args.plot)
        print(f"wrote {args.plot}")


if __name__ == "__main__":
    main()
