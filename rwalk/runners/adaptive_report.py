"""Figures of docs/adaptive.md: an adaptive and a residual policy against the base gait.

    python -m runners.adaptive_report --residual logs/residual/model_399.pt \\
        --adaptive logs/adaptive/model_399.pt --out docs

Every row runs the same --episodes paired episodes (episode i starts like a
single env seeded --seed + i): (a) on the training terrain (--train-scale), (b)
on rougher terrain (--rough-scale), (c) at each commanded speed on the training
terrain: the speed is each episode's target velocity, which the reward and the
velocity error track; only the adaptive policy (trained with commands) reads it,
the base gait and the residual policy walk as they do. Writes adaptive.json
(every row) and adaptive_gait.png (the adaptive policy's gait parameters over
one episode on smooth and rough ground), and prints the tables.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

from rwalk.adaptive_evaluation import compare, gait_traces, plot, table
from rwalk.cli import NATURAL_INT, POSITIVE_INT, UNIT_FLOAT, one_line_errors
from rwalk.evaluation import Evaluation, check_policy, read_results
from rwalk.rl.checkpoints import atomic_write_text


@one_line_errors("rwalk.runners.adaptive_report")
def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    add = parser.add_argument
    add("--residual", type=Path, help="residual checkpoint")
    add("--adaptive", type=Path, help="adaptive checkpoint")
    add("--episodes", type=POSITIVE_INT, default=100, help="paired episodes")
    add("--seed", type=NATURAL_INT, default=1000, help="first episode's seed")
    add("--train-scale", type=UNIT_FLOAT, default=0.6, help="training terrain")
    add("--rough-scale", type=UNIT_FLOAT, default=1.0, help="rougher terrain")
    add("--out", type=Path, default=Path("docs"), help="output folder")
    add("--tables", type=Path, help="only print the tables of an adaptive.json")
    args = parser.parse_args(argv)
    if args.tables:
        try:
            data = read_results(args.tables)
            tables = {label: [Evaluation.from_json(row) for row in data[label]]
                      for label in ("a", "b", "c")}  # fmt: skip
        except (OSError, ValueError, KeyError, TypeError) as error:
            parser.error(f"--tables: not an adaptive.json of this report ({error})")
        for label, rows in tables.items():
            print(f"\n({label})\n{table(rows)}")
        return
    if args.residual is None or args.adaptive is None:
        parser.error("give --residual and --adaptive checkpoints (or --tables)")
    for flag, path, task in (("--residual", args.residual, "residual_walk"),
                             ("--adaptive", args.adaptive, "adaptive_gait")):  # fmt: skip
        try:  # every file, before any row runs
            check_policy(path, task)
        except (OSError, ValueError) as error:
            parser.error(f"{flag}: {error}")
    policies = {"base gait": None, "residual": args.residual, "adaptive": args.adaptive}
    out = compare(policies, args.episodes, args.seed, args.train_scale, args.rough_scale)
    for label, rows in out.items():
        print(f"\n({label})\n{table(rows)}")
    args.out.mkdir(parents=True, exist_ok=True)
    data = {k: [dataclasses.asdict(r) for r in rows] for k, rows in out.items()}
    traces = gait_traces(args.adaptive, args.seed, (0.0, args.train_scale, args.rough_scale))
    data["gait_means"] = {k: v.mean(axis=0).tolist() for k, v in traces.items()}
    print("\nmean gait parameters over the traced episode:", data["gait_means"])
    atomic_write_text(args.out / "adaptive.json", json.dumps(data, indent=2))
    plot(traces, args.out / "adaptive_gait.png")


if __name__ == "__main__":
    main()
